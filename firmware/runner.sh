#!/bin/sh
# cargo's runner for thumbv7em-none-eabihf (.cargo/config.toml): picks the board by the
# image's name, which the two bins tell apart (firmware/Cargo.toml).
#   maobi-pen: the Black Pill: flash it with probe-rs and show its defmt log (RTT).
#   anything else (maobi-fw): boot it in QEMU's mps2-an386, serial on stdio.
# Arguments after the image (`cargo run -- ARGS`) go to probe-rs or QEMU unchanged.
set -eu
elf="$1"
shift
case "$(basename "$elf")" in
maobi-pen)
    exec probe-rs run --chip STM32F411CEUx "$elf" "$@"
    ;;
*)
    exec timeout 60 qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic \
        -monitor none -semihosting-config enable=on,target=native \
        -icount shift=0,sleep=off -kernel "$elf" "$@"
    ;;
esac
