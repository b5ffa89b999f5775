#!/usr/bin/env bash
# cargo's runner for thumbv7em-none-eabihf (.cargo/config.toml): picks the board by the
# image's name, which the two bins tell apart (firmware/Cargo.toml).
#   maobi-pen: the Black Pill: flash it with probe-rs and show its defmt log (RTT).
#   anything else (maobi-fw): boot it in QEMU's mps2-an386, serial on stdio, and its defmt
#   log (semihosting stderr) decoded by defmt-print (`cargo install defmt-print`).
# Arguments after the image (`cargo run -- ARGS`) go to probe-rs or QEMU unchanged.
set -euo pipefail
elf="$1"
shift
case "$(basename "$elf")" in
maobi-pen)
    exec probe-rs run --chip STM32F411CEUx "$elf" "$@"
    ;;
*)
    qemu() {
        timeout 60 qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic \
            -monitor none -semihosting-config enable=on,target=native \
            -icount shift=0,sleep=off -kernel "$elf" "$@"
    }
    if command -v defmt-print >/dev/null 2>&1; then
        # QEMU's stdout stays stdout; its stderr (the defmt frames) goes through the decoder.
        { qemu "$@" 2>&1 1>&3 3>&- | defmt-print -e "$elf" >&2; } 3>&1
    else
        echo "runner: defmt-print not found: the firmware's defmt log is not shown" \
            "(cargo install defmt-print)" >&2
        exec 2>/dev/null
        qemu "$@"
    fi
    ;;
esac
