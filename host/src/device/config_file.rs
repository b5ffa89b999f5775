//! The pen's stored configuration as a TOML file a builder edits: `maobi device config
//! template | get | set | check`.
//!
//! The file is [`DeviceConfig`] through serde, so its keys are the struct's field names and
//! the firmware's validation messages (`pen.ratio`, `drive[1].deadband`) name the same keys.
//! Reading is strict: a malformed file is reported with its line and column, a key the
//! configuration does not have (a typo) is an error rather than silently ignored, and every
//! value is validated with the same [`DeviceConfig::validate`] the pen runs before anything is
//! sent. Written files carry a comment per key (units, meaning), so the template documents
//! itself.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::time::Duration;

use maobi_shared::pen_io::{ConfigState, DeviceConfig, InvalidField, OverCurrent};
use maobi_shared::protocol::{Capabilities, ConfigRejected};

use super::bringup::Wire;

/// Why a configuration file was not accepted.
#[derive(Debug)]
pub enum ConfigFileError {
    /// Not TOML, a missing key or a value of the wrong type (the message has line and column).
    Parse(String),
    /// Keys the configuration does not have, as `table.key` paths.
    UnknownKeys(Vec<String>),
    /// A value out of its range.
    Invalid(InvalidField),
    /// A duty clamp that lets a stalled motor draw more than the driver's rating (the same
    /// check as [`Self::Invalid`]'s `drive[j].max_duty`, with the currents that explain it).
    OverCurrent(OverCurrent),
}

impl fmt::Display for ConfigFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigFileError::Parse(e) => write!(f, "{}", e.trim_end()),
            ConfigFileError::UnknownKeys(k) => write!(
                f,
                "unknown key{} {} (a typo? `maobi device config template` lists every key)",
                if k.len() == 1 { "" } else { "s" },
                k.iter()
                    .map(|k| format!("`{k}`"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            ConfigFileError::Invalid(field) => write!(f, "{field}"),
            ConfigFileError::OverCurrent(over) => write!(f, "{over}"),
        }
    }
}

impl std::error::Error for ConfigFileError {}

/// Parses and validates a configuration file's text.
pub fn from_toml(text: &str) -> Result<DeviceConfig, ConfigFileError> {
    let cfg: DeviceConfig =
        toml::from_str(text).map_err(|e| ConfigFileError::Parse(e.to_string()))?;
    // serde ignores keys a struct does not have; compare with what the parsed value writes.
    let given: toml::Table =
        toml::from_str(text).map_err(|e| ConfigFileError::Parse(e.to_string()))?;
    let known: toml::Table = toml::Table::try_from(cfg)
        .map_err(|e| ConfigFileError::Parse(format!("cannot re-encode the configuration: {e}")))?;
    let mut unknown = Vec::new();
    unknown_keys(
        "",
        &toml::Value::Table(given),
        &toml::Value::Table(known),
        &mut unknown,
    );
    if !unknown.is_empty() {
        return Err(ConfigFileError::UnknownKeys(unknown));
    }
    // The pen's own validation; its over-current refusal is explained with the currents.
    cfg.validate().map_err(|field| match cfg.over_current() {
        Some(over) if field.field.ends_with("].max_duty") => ConfigFileError::OverCurrent(over),
        _ => ConfigFileError::Invalid(field),
    })?;
    Ok(cfg)
}

/// Each channel's current with its motor stalled at the duty clamp, and the driver's
/// rating: what `maobi device config check` reports of a valid file.
pub fn stall_currents(cfg: &DeviceConfig) -> String {
    let each: Vec<String> = (0..cfg.drive.len())
        .map(|j| format!("{:.2} A", cfg.stall_current_a(j)))
        .collect();
    format!(
        "stall currents at the duty clamps {} (motors 1, 2, 3) at {} V, within the driver's {} A",
        each.join(", "),
        cfg.power.supply_v,
        cfg.power.driver_current_a
    )
}

/// What the pen would accept but the builder's guide advises against, one line each: a
/// `pen.max_current` above its motor's stall current at the duty clamp (the motor cannot draw
/// it, so full command gives less torque than the force model counts on, and every force
/// comes out weaker than asked).
pub fn warnings(cfg: &DeviceConfig) -> Vec<String> {
    let mut out = Vec::new();
    for (j, (&max, d)) in cfg.pen.max_current.iter().zip(&cfg.drive).enumerate() {
        let stall = cfg.stall_current_a(j);
        // Within what two decimals hide: a value copied from the printed stall current
        // passes.
        if max - stall <= 0.005 {
            continue;
        }
        // Rounded down, so that the suggestion passes this check.
        let suggest = (stall * 100.0).floor() / 100.0;
        out.push(format!(
            "pen.max_current[{j}] = {max} A is more than motor {}'s stall current at its duty \
             clamp, {stall:.2} A (power.supply_v {} V x drive[{j}].max_duty {} / {} Ohm): the \
             motor cannot draw it, so the pen's forces come out weaker than the model asks. \
             Set pen.max_current[{j}] = {suggest} (or correct power.supply_v, \
             drive[{j}].max_duty or drive[{j}].winding_mohm if one of them is wrong)",
            j + 1,
            cfg.power.supply_v,
            d.max_duty,
            d.winding_ohm(),
        ));
    }
    out
}

/// Reads and validates a configuration file; errors name the file.
pub fn load(path: &Path) -> anyhow::Result<DeviceConfig> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    from_toml(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Paths of `given`'s keys that `known` lacks (arrays of tables are compared element-wise).
fn unknown_keys(at: &str, given: &toml::Value, known: &toml::Value, out: &mut Vec<String>) {
    match (given, known) {
        (toml::Value::Table(g), toml::Value::Table(k)) => {
            for (key, gv) in g {
                let path = if at.is_empty() {
                    key.clone()
                } else {
                    format!("{at}.{key}")
                };
                match k.get(key) {
                    Some(kv) => unknown_keys(&path, gv, kv, out),
                    None => out.push(path),
                }
            }
        }
        (toml::Value::Array(g), toml::Value::Array(k)) => {
            for (i, (gv, kv)) in g.iter().zip(k).enumerate() {
                unknown_keys(&format!("{at}[{i}]"), gv, kv, out);
            }
        }
        _ => {}
    }
}

/// The configuration the pen has in force; an error that says what to do when it has none.
pub fn read_from_pen(wire: &mut Wire, timeout: Duration) -> anyhow::Result<DeviceConfig> {
    match wire.get_config(timeout).map_err(|e| anyhow::anyhow!(e))? {
        Ok(cfg) => Ok(cfg),
        Err(ConfigRejected::NotStored(state)) => anyhow::bail!(
            "the pen has no configuration in force ({state}); write one with `maobi device \
             config set FILE` (start from `maobi device config template`)"
        ),
        Err(why) => anyhow::bail!("the pen refused: {why}"),
    }
}

/// What [`write_to_pen`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Written {
    /// The pen's configuration before (none: it had no valid one).
    pub before: Option<DeviceConfig>,
    /// What the pen stored and answered with (equal to what was sent).
    pub stored: DeviceConfig,
}

/// Writes `cfg` to the pen and checks the answer is what was sent. Without a calibration in
/// `cfg` the pen's own is kept unless `clear_calibration`: calibration is a measurement of
/// this pen in its inkwell, which a file written from the template does not have.
pub fn write_to_pen(
    wire: &mut Wire,
    mut cfg: DeviceConfig,
    clear_calibration: bool,
    timeout: Duration,
) -> anyhow::Result<Written> {
    let before = match wire.get_config(timeout).map_err(|e| anyhow::anyhow!(e))? {
        Ok(old) => Some(old),
        Err(ConfigRejected::NotStored(ConfigState::NotApplicable)) => anyhow::bail!(
            "this device keeps no configuration ({})",
            if wire.info.capabilities.contains(Capabilities::VIRTUAL_PEN) {
                "a virtual pen: the QEMU board without a store, the simulator"
            } else {
                "a device behind a bridge, such as `maobi bridge`'s Phantom, whose own \
                 library holds its settings"
            }
        ),
        Err(ConfigRejected::NotStored(_)) => None,
        Err(why) => anyhow::bail!("the pen refused to give its configuration: {why}"),
    };
    if clear_calibration {
        cfg.calibration = None;
    } else if cfg.calibration.is_none() {
        cfg.calibration = before.and_then(|o| o.calibration);
    }
    let stored = match wire
        .set_config(cfg, timeout)
        .map_err(|e| anyhow::anyhow!(e))?
    {
        Ok(stored) => stored,
        Err(why) => anyhow::bail!("the pen did not store the configuration: {why}"),
    };
    if stored != cfg {
        anyhow::bail!(
            "the pen stored a different configuration than was sent: {}",
            changes(&cfg, &stored).join("; ")
        );
    }
    Ok(Written { before, stored })
}

/// What each key means, by table, in the order the file has them.
const COMMENTS: &[(&str, &str, &str)] = &[
    ("pen", "upper_arm_mm", "shoulder to elbow (mm)"),
    (
        "pen",
        "forearm_mm",
        "elbow to wrist, the gimbal's centre (mm)",
    ),
    ("pen", "stylus_mm", "wrist to ferrule along the stylus (mm)"),
    (
        "pen",
        "base_mm",
        "the shoulder's position in the paper frame, x y z (mm; z up)",
    ),
    (
        "pen",
        "counts_per_rev",
        "encoder counts per motor revolution, after quadrature decoding",
    ),
    (
        "pen",
        "ratio",
        "motor revolutions per joint revolution (capstan or gear ratio)",
    ),
    (
        "pen",
        "encoder_sign",
        "+1 or -1: which way a rising count turns each joint",
    ),
    ("pen", "torque_constant", "motor torque constant (N m / A)"),
    (
        "pen",
        "max_current",
        "motor current at full command (A): the stall current at the duty clamp, power.supply_v x drive.max_duty / the winding's resistance",
    ),
    (
        "pen",
        "motor_sign",
        "+1 or -1: which way a positive command turns each joint (`maobi device check` finds it)",
    ),
    ("pen", "joint_min", "joint limits (rad)"),
    ("pen", "joint_max", ""),
    (
        "pen",
        "gimbal_rad_per_code",
        "gimbal sensors: radians per ADC code",
    ),
    ("pen", "gimbal_sign", "+1 or -1 per gimbal sensor"),
    (
        "pen",
        "inkwell_joints",
        "joint angles of the inkwell, the calibration pose (rad)",
    ),
    (
        "pen",
        "inkwell_gimbal",
        "gimbal angles of the inkwell (rad)",
    ),
    ("drive", "pwm_hz", "PWM frequency (Hz), 20000 ..= 100000"),
    (
        "drive",
        "deadband",
        "duty the smallest non-zero command gets (fraction, 0 ..= 0.5)",
    ),
    (
        "drive",
        "max_duty",
        "largest duty any command gets (fraction, above the deadband, at most 1, and at most power.driver_current_a x the winding's resistance / power.supply_v, so that a stalled motor stays within the driver's rating)",
    ),
    (
        "drive",
        "zero",
        "what a zero command does: \"Coast\" (bridge off) or \"Brake\" (winding shorted)",
    ),
    (
        "drive",
        "winding_mohm",
        "the motor's winding resistance (milliohms, at least 100): measured across its terminals with the shaft still, or rated voltage / stall current",
    ),
    (
        "power",
        "supply_v",
        "motor supply at the drivers' VM (V), at most 13.5 (the TB6612's limit)",
    ),
    (
        "power",
        "driver_current_a",
        "the driver's continuous current per channel (A): 1.2 for the TB6612 (its 3.2 A peak holds for milliseconds only)",
    ),
    ("limits", "peak_n", "largest force, briefly (N)"),
    (
        "limits",
        "continuous_n",
        "largest force, indefinitely: the motors' heating (N)",
    ),
    (
        "limits",
        "thermal_time_s",
        "time constant of the thermal average of |F|^2 (s)",
    ),
    (
        "limits",
        "max_step_n",
        "largest change of the force between two 1 ms ticks (N)",
    ),
    (
        "limits",
        "ramp_in_s",
        "forces fade in over this time after enabling (s)",
    ),
    (
        "limits",
        "ramp_out_s",
        "on a fault or disable, forces fade out over this time (s; 0: at once)",
    ),
    (
        "limits",
        "damping_ns_per_m",
        "the pen's own damping at the handle: back-EMF, friction (N s/m)",
    ),
    (
        "calibration",
        "encoders",
        "raw readings in the inkwell, recorded by Calibrate: unwrapped encoder counts",
    ),
    ("calibration", "gimbal", "and gimbal ADC codes"),
];

const TABLE_COMMENTS: &[(&str, &str)] = &[
    (
        "pen",
        "The arm's geometry, encoders, motors and the inkwell.",
    ),
    (
        "drive",
        "One H-bridge channel per motor, in joint order (base, shoulder, elbow).",
    ),
    (
        "power",
        "The motor supply and the driver's rating: with each winding resistance they bound the duty.",
    ),
    (
        "limits",
        "Force limits of this pen's motors. Lower them for the first strokes.",
    ),
    (
        "calibration",
        "Written by `Calibrate` (`maobi device check`, step 4); leave it out to keep the pen's.",
    ),
];

/// The configuration as TOML with a comment on every key; `title` heads the file.
pub fn to_toml(cfg: &DeviceConfig, title: &str) -> String {
    let plain = toml::to_string(cfg).unwrap_or_default();
    let comments: BTreeMap<(&str, &str), &str> =
        COMMENTS.iter().map(|(t, k, c)| ((*t, *k), *c)).collect();
    let mut out = String::new();
    for line in title.lines() {
        out.push_str(&format!("# {line}\n").replace("# \n", "#\n"));
    }
    out.push_str(
        "# The Maobi pen's stored configuration (maobi_shared::pen_io::DeviceConfig).\n\
         # Write it with `maobi device config set FILE`; every value is checked first.\n",
    );
    let mut table = "";
    let mut first_of_table = true;
    for line in plain.lines() {
        let trimmed = line.trim();
        if let Some(name) = trimmed
            .strip_prefix("[[")
            .and_then(|s| s.strip_suffix("]]"))
            .or_else(|| trimmed.strip_prefix('[').and_then(|s| s.strip_suffix(']')))
        {
            let repeat = name == table;
            table = TABLE_COMMENTS
                .iter()
                .map(|(t, _)| *t)
                .find(|t| *t == name)
                .unwrap_or("");
            first_of_table = !repeat;
            if first_of_table {
                if let Some((_, c)) = TABLE_COMMENTS.iter().find(|(t, _)| *t == name) {
                    out.push_str(&format!("\n# {c}\n"));
                }
            }
            out.push_str(line);
            out.push('\n');
            continue;
        }
        if let Some((key, _)) = trimmed.split_once(" = ") {
            if first_of_table {
                if let Some(c) = comments.get(&(table, key)).filter(|c| !c.is_empty()) {
                    out.push_str(&format!("# {c}\n"));
                }
            }
        }
        if !trimmed.is_empty() {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// The keys whose values differ between two configurations, as `key: old -> new` lines.
pub fn changes(old: &DeviceConfig, new: &DeviceConfig) -> Vec<String> {
    let (Some(a), Some(b)) = (as_table(old), as_table(new)) else {
        return vec![];
    };
    let mut out = Vec::new();
    diff("", &toml::Value::Table(a), &toml::Value::Table(b), &mut out);
    out
}

/// The configuration as a TOML table, through its text, so that an `f32` keeps its shortest
/// decimal form (a direct conversion widens 13.2 to 13.199999809265137).
fn as_table(cfg: &DeviceConfig) -> Option<toml::Table> {
    toml::from_str(&toml::to_string(cfg).ok()?).ok()
}

fn diff(at: &str, a: &toml::Value, b: &toml::Value, out: &mut Vec<String>) {
    let join = |k: &str| {
        if at.is_empty() {
            k.to_string()
        } else {
            format!("{at}.{k}")
        }
    };
    match (a, b) {
        (toml::Value::Table(ta), toml::Value::Table(tb)) => {
            for (k, va) in ta {
                match tb.get(k) {
                    Some(vb) => diff(&join(k), va, vb, out),
                    None => out.push(format!("{}: {va} -> (none)", join(k))),
                }
            }
            for (k, vb) in tb {
                if !ta.contains_key(k) {
                    out.push(format!("{}: (none) -> {vb}", join(k)));
                }
            }
        }
        (toml::Value::Array(xa), toml::Value::Array(xb))
            if xa.len() == xb.len() && xa.iter().all(|v| v.is_table()) =>
        {
            for (i, (va, vb)) in xa.iter().zip(xb).enumerate() {
                diff(&format!("{at}[{i}]"), va, vb, out);
            }
        }
        _ if a != b => out.push(format!("{at}: {a} -> {b}")),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use maobi_shared::kinematics::RawReadings;

    fn calibrated() -> DeviceConfig {
        DeviceConfig {
            calibration: Some(RawReadings {
                encoders: [120, -3400, 77],
                gimbal: [2048, 1990, 2101],
            }),
            ..DeviceConfig::DEFAULT
        }
    }

    #[test]
    fn files_round_trip_exactly_with_a_comment_on_every_key() {
        for cfg in [DeviceConfig::DEFAULT, calibrated()] {
            let text = to_toml(&cfg, "test");
            assert_eq!(from_toml(&text).unwrap(), cfg, "{text}");
            for (table, key, comment) in COMMENTS {
                if comment.is_empty() || (*table == "calibration" && cfg.calibration.is_none()) {
                    continue;
                }
                assert!(
                    text.contains(&format!("# {comment}\n")),
                    "{table}.{key}:\n{text}"
                );
            }
            // The comment comes once, not before every [[drive]].
            assert_eq!(text.matches("# PWM frequency").count(), 1);
        }
    }

    #[test]
    fn a_malformed_file_names_line_and_column() {
        let text =
            to_toml(&DeviceConfig::DEFAULT, "t").replace("ratio = [13.2,", "ratio = [\"13.2\",");
        let e = from_toml(&text).unwrap_err().to_string();
        assert!(e.contains("line ") && e.contains("column "), "{e}");
        let line = text.lines().position(|l| l.starts_with("ratio")).unwrap() + 1;
        assert!(e.contains(&format!("line {line}")), "{e}");
    }

    #[test]
    fn a_typo_is_an_unknown_key_not_a_silent_default() {
        // An extra key (the struct has every field already).
        let text = to_toml(&calibrated(), "t").replace("[limits]\n", "[limits]\npeak = 2.0\n");
        let e = from_toml(&text).unwrap_err();
        assert!(
            matches!(&e, ConfigFileError::UnknownKeys(k) if k == &["limits.peak"]),
            "{e}"
        );
        let text = to_toml(&calibrated(), "t").replacen(
            "pwm_hz = 25000\n",
            "pwm_hz = 25000\nfreq = 1\n",
            2,
        );
        let e = from_toml(&text).unwrap_err().to_string();
        assert!(e.contains("`drive[0].freq`, `drive[1].freq`"), "{e}");
        // A misspelt required key: the missing one is named.
        let text = to_toml(&calibrated(), "t").replace("forearm_mm", "fore_arm_mm");
        let e = from_toml(&text).unwrap_err().to_string();
        assert!(e.contains("forearm_mm"), "{e}");
    }

    #[test]
    fn out_of_range_values_are_named_as_the_pen_names_them() {
        let text =
            to_toml(&DeviceConfig::DEFAULT, "t").replacen("deadband = 0.04", "deadband = 0.9", 1);
        let e = from_toml(&text).unwrap_err();
        let ConfigFileError::Invalid(f) = &e else {
            panic!("{e}")
        };
        assert_eq!(f.field.as_str(), "drive[0].deadband");
        let text = to_toml(&DeviceConfig::DEFAULT, "t").replace("peak_n = 3.3", "peak_n = nan");
        assert!(matches!(from_toml(&text), Err(ConfigFileError::Invalid(_))));
    }

    #[test]
    fn a_duty_that_would_overload_the_driver_is_refused_with_the_currents() {
        let text = to_toml(&DeviceConfig::DEFAULT, "t");
        assert!(stall_currents(&from_toml(&text).unwrap()).contains("1.09 A, 1.09 A, 1.09 A"));
        // The old default duty clamp, 0.95, on motor 2: 5.18 A into a stalled motor.
        let at = text.match_indices("max_duty = 0.2\n").nth(1).unwrap().0;
        let bad = format!("{}max_duty = 0.95\n{}", &text[..at], &text[at + 15..]);
        let e = from_toml(&bad).unwrap_err();
        let ConfigFileError::OverCurrent(over) = &e else {
            panic!("{e}")
        };
        assert_eq!(over.channel, 1);
        let said = e.to_string();
        for part in [
            "drive[1].max_duty = 0.95",
            "5.18 A (12 V x 0.95 / 2.2 Ohm)",
            "driver's rating of 1.2 A",
            "at most 0.22",
        ] {
            assert!(said.contains(part), "{part}: {said}");
        }
        // A motor of lower resistance at the default clamp, a supply above the driver's.
        let bad = text.replacen("winding_mohm = 2200", "winding_mohm = 1000", 1);
        assert!(from_toml(&bad)
            .unwrap_err()
            .to_string()
            .ends_with("at most 0.1"));
        let bad = text.replace("supply_v = 12.0", "supply_v = 15.0");
        assert!(from_toml(&bad)
            .unwrap_err()
            .to_string()
            .starts_with("power.supply_v: 15"));
    }

    #[test]
    fn changes_list_the_keys_that_differ() {
        let mut b = calibrated();
        b.pen.ratio[1] = 10.0;
        b.drive[2].deadband = 0.06;
        let c = changes(&DeviceConfig::DEFAULT, &b);
        assert_eq!(c.len(), 3, "{c:?}");
        assert!(
            c.iter().any(|l| l.starts_with("calibration: (none) -> ")),
            "{c:?}"
        );
        assert!(
            c.iter()
                .any(|l| l.starts_with("drive[2].deadband: 0.04 -> 0.06")),
            "{c:?}"
        );
        assert!(
            c.iter()
                .any(|l| l.starts_with("pen.ratio: [13.2, 13.2, 13.2] -> [13.2, 10.0, 13.2]")),
            "{c:?}"
        );
        assert!(changes(&b, &b).is_empty());
    }
}
