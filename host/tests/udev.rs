//! The udev rules file names the pen by the USB IDs the firmware enumerates with.

use maobi_shared::protocol::{USB_PID, USB_VID};

#[test]
fn the_udev_rules_name_the_pens_usb_ids() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/udev/70-maobi.rules");
    let rules = std::fs::read_to_string(path).unwrap();
    let pen =
        format!("ATTRS{{idVendor}}==\"{USB_VID:04x}\", ATTRS{{idProduct}}==\"{USB_PID:04x}\"");
    let lines: Vec<&str> = rules
        .lines()
        .filter(|l| !l.trim_start().starts_with('#') && l.contains(&pen))
        .collect();
    assert_eq!(lines.len(), 2, "the tty rule and ModemManager's: {lines:?}");
    assert!(lines
        .iter()
        .any(|l| l.contains("SUBSYSTEM==\"tty\"") && l.contains("uaccess")));
    assert!(lines.iter().any(|l| l.contains("ID_MM_DEVICE_IGNORE")));
    // Every rule line is `KEY==\"...\"` / `KEY=\"...\"` / `KEY+=\"...\"` pairs, comma-separated.
    for l in rules
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
    {
        for pair in l.split(", ") {
            let ok = ["==", "+=", "="].iter().any(|op| {
                pair.split_once(op)
                    .is_some_and(|(k, v)| !k.is_empty() && v.starts_with('"') && v.ends_with('"'))
            });
            assert!(ok, "not a udev key/value pair: `{pair}` in `{l}`");
        }
    }
}
