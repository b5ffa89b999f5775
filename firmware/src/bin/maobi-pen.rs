//! `maobi-pen`: the Maobi firmware on the STM32F411CE Black Pill in the real pen (feature
//! `board-blackpill`); `cargo pen` flashes it and shows its log.
#![no_std]
#![no_main]

#[cortex_m_rt::entry]
fn main() -> ! {
    maobi_firmware::blackpill::main()
}
