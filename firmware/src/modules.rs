// The modules and board checks of both images' crate roots (`main.rs`: `maobi-fw` for QEMU,
// `pen.rs`: `maobi-pen` for the Black Pill): one application, the board picked by feature.

#[cfg(all(feature = "board-qemu", feature = "board-blackpill"))]
compile_error!(
    "select exactly one board: `board-qemu` is the default; build the Black Pill with \
     `--no-default-features --features board-blackpill`"
);
#[cfg(not(any(feature = "board-qemu", feature = "board-blackpill")))]
compile_error!("select a board feature: `board-qemu` (default) or `board-blackpill`");

mod app;
mod board;
mod executor;
mod host_link;

#[cfg(feature = "board-blackpill")]
mod blackpill;
#[cfg(feature = "board-qemu")]
mod qemu;
