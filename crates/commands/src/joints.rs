//! The bus's CiA 402 axes as `joint_commands` resolves them, and the rule that decides which
//! `sensor_msgs/JointState` commands the native path may apply by itself.
//!
//! The node's Python code (`ether_ros.ros.bridge.resolve_joint_command` with
//! `Axis.check_command`) is the reference, as for the writes (see [`crate::table`]): a command
//! is applied here only when Python would certainly apply it, with the same values; anything
//! else (an unknown or repeated joint, a missing, NaN or out-of-limit value, the wrong kind for
//! the mode, arrays whose lengths differ from the names) is deferred to Python, which refuses
//! it with a message. `tests/unit/test_native_commands.py` checks the two against each other.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use ether_ros_engine::SetpointKind;

use crate::cdr::{F64Seq, JointCommand};
use crate::table::Resolution;

/// One axis: its joint name, its index in the engine and its limits (SI units).
#[derive(Debug, Clone, PartialEq)]
pub struct JointEntry {
    /// The joint name a `JointState` message uses for this axis.
    pub name: String,
    /// Index of the axis in the engine's plan.
    pub axis: usize,
    /// Lowest position a command may ask for (SI units, from the axis config).
    pub position_min: f64,
    /// Highest position a command may ask for.
    pub position_max: f64,
    /// Largest velocity magnitude a command may ask for.
    pub velocity_limit: f64,
    /// Largest torque magnitude a command may ask for.
    pub torque_limit: f64,
}

/// The axes of a bus. The setpoint kind each one takes (from its mode) can change while the
/// table is attached (`set_kind`, after a mode switch); clones share it.
#[derive(Debug, Clone)]
pub struct JointTable {
    joints: Arc<[JointEntry]>,
    /// SetpointKind as u8 per joint; 0: none (homing, or a mode switch in progress).
    kinds: Arc<[AtomicU8]>,
}

/// One setpoint to write: (engine axis index, kind, SI value).
pub type Setpoint = (usize, SetpointKind, f64);

impl JointTable {
    /// `joints` with their current setpoint kinds. Names must be unique.
    pub fn new(joints: Vec<(JointEntry, Option<SetpointKind>)>) -> Result<JointTable, String> {
        for (i, (j, _)) in joints.iter().enumerate() {
            if joints[..i].iter().any(|(k, _)| k.name == j.name) {
                return Err(format!("joint '{}' is named twice", j.name));
            }
        }
        let kinds = joints
            .iter()
            .map(|(_, k)| AtomicU8::new(k.map_or(0, |k| k as u8)))
            .collect();
        Ok(JointTable {
            joints: joints.into_iter().map(|(j, _)| j).collect(),
            kinds,
        })
    }

    /// The kind joint number `joint` takes from now on (None: every command for it goes to
    /// Python). Out-of-range numbers are ignored.
    pub fn set_kind(&self, joint: usize, kind: Option<SetpointKind>) {
        if let Some(k) = self.kinds.get(joint) {
            k.store(kind.map_or(0, |k| k as u8), Ordering::Release);
        }
    }

    /// Number of joints in the table.
    pub fn len(&self) -> usize {
        self.joints.len()
    }

    /// True when the bus has no joint (joint commands are then refused).
    pub fn is_empty(&self) -> bool {
        self.joints.is_empty()
    }

    /// Resolve a decoded command (`names` from `decode_joint_state`): `Apply` with every
    /// setpoint in `out` (cleared first), or `Defer` (also for what `resolve_or_refuse` would
    /// refuse).
    pub fn resolve(
        &self,
        cmd: &JointCommand<'_>,
        names: &[&str],
        out: &mut Vec<Setpoint>,
    ) -> Resolution {
        let mut why = String::new();
        match self.resolve_or_refuse(cmd, names, out, &mut why) {
            Resolution::Refuse => Resolution::Defer,
            r => r,
        }
    }

    /// As `resolve`, and `Refuse` (with Python's words in `why`, cleared first) for what is
    /// certainly invalid by its structure: no names, an array whose length differs from the
    /// names, a joint named twice or not on this bus. Python
    /// (`bridge.resolve_joint_command`) checks in the same order, so the first problem it
    /// would name is the one named here; at the first check only Python can make (a value, a
    /// mode) this defers instead.
    pub fn resolve_or_refuse(
        &self,
        cmd: &JointCommand<'_>,
        names: &[&str],
        out: &mut Vec<Setpoint>,
        why: &mut String,
    ) -> Resolution {
        use std::fmt::Write as _;
        out.clear();
        why.clear();
        let n = names.len();
        if n == 0 {
            why.push_str("no joint names");
            return Resolution::Refuse;
        }
        let arrays = [cmd.position, cmd.velocity, cmd.effort];
        for (label, a) in ["position", "velocity", "effort"].iter().zip(arrays) {
            if !a.is_empty() && a.len() != n {
                let _ = write!(
                    why,
                    "{label} has {} value(s) for {n} joint name(s) (give one per name, or none)",
                    a.len()
                );
                return Resolution::Refuse;
            }
        }
        for (i, name) in names.iter().enumerate() {
            let plain = python_plain(name);
            let earlier = names[..i].contains(name);
            let Some(j) = self.joints.iter().position(|e| e.name == *name) else {
                if !plain || earlier {
                    return Resolution::Defer;
                }
                let _ = write!(why, "unknown joint '{name}' (joints: ");
                for (k, e) in self.joints.iter().enumerate() {
                    why.push_str(if k == 0 { "" } else { ", " });
                    why.push_str(&e.name);
                }
                why.push(')');
                return Resolution::Refuse;
            };
            let entry = &self.joints[j];
            if earlier {
                if !plain {
                    return Resolution::Defer;
                }
                let _ = write!(why, "joint '{name}' is named twice");
                return Resolution::Refuse;
            }
            let Some(kind) = SetpointKind::from_code(self.kinds[j].load(Ordering::Acquire)) else {
                return Resolution::Defer;
            };
            let values: F64Seq<'_> = match kind {
                SetpointKind::Position => cmd.position,
                SetpointKind::Velocity => cmd.velocity,
                SetpointKind::Torque => cmd.effort,
            };
            if values.is_empty() {
                return Resolution::Defer;
            }
            let v = values.get(i);
            let within = match kind {
                SetpointKind::Position => entry.position_min <= v && v <= entry.position_max,
                SetpointKind::Velocity => v.abs() <= entry.velocity_limit,
                SetpointKind::Torque => v.abs() <= entry.torque_limit,
            };
            if !v.is_finite() || !within {
                return Resolution::Defer;
            }
            out.push((entry.axis, kind, v));
        }
        Resolution::Apply
    }
}

/// Whether Python's `repr(name)` is `'name'`: printable ASCII without quote or backslash (for
/// any other name the refusal is left to Python, which words it).
fn python_plain(name: &str) -> bool {
    name.bytes()
        .all(|b| (0x20..0x7F).contains(&b) && b != b'\'' && b != b'\\')
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::decode_joint_state;

    fn table() -> JointTable {
        let joint = |name: &str, axis| JointEntry {
            name: name.into(),
            axis,
            position_min: -1.0,
            position_max: 2.0,
            velocity_limit: 3.0,
            torque_limit: 4.0,
        };
        JointTable::new(vec![
            (joint("a", 0), Some(SetpointKind::Position)),
            (joint("b", 1), Some(SetpointKind::Velocity)),
        ])
        .unwrap()
    }

    /// A little-endian JointState with an empty header.
    fn message(names: &[&str], position: &[f64], velocity: &[f64]) -> Vec<u8> {
        let mut b = vec![0, 1, 0, 0];
        let pad = |b: &mut Vec<u8>, to: usize| {
            while !(b.len() - 4).is_multiple_of(to) {
                b.push(0xEE);
            }
        };
        b.extend_from_slice(&[0; 8]);
        b.extend_from_slice(&1u32.to_le_bytes());
        b.push(0);
        pad(&mut b, 4);
        b.extend_from_slice(&(names.len() as u32).to_le_bytes());
        for n in names {
            b.extend_from_slice(&(n.len() as u32 + 1).to_le_bytes());
            b.extend_from_slice(n.as_bytes());
            b.push(0);
            pad(&mut b, 4);
        }
        for seq in [position, velocity, &[]] {
            pad(&mut b, 4);
            b.extend_from_slice(&(seq.len() as u32).to_le_bytes());
            if !seq.is_empty() {
                pad(&mut b, 8);
            }
            for v in seq {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        b
    }

    fn resolve(t: &JointTable, data: &[u8]) -> (Resolution, Vec<Setpoint>) {
        let mut names = Vec::new();
        let cmd = decode_joint_state(data, &mut names).unwrap();
        let mut out = Vec::new();
        let r = t.resolve(&cmd, &names, &mut out);
        (r, out)
    }

    #[test]
    fn applies_the_kind_each_mode_takes() {
        let t = table();
        let (r, out) = resolve(&t, &message(&["b", "a"], &[1.5, 0.5], &[-2.0, 9.0]));
        assert_eq!(r, Resolution::Apply);
        assert_eq!(
            out,
            [
                (1, SetpointKind::Velocity, -2.0),
                (0, SetpointKind::Position, 0.5)
            ]
        );
    }

    #[test]
    fn defers_what_python_must_refuse() {
        let t = table();
        for data in [
            message(&[], &[], &[]),
            message(&["x"], &[0.0], &[]),
            message(&["a", "a"], &[0.0, 0.1], &[]),
            message(&["a"], &[f64::NAN], &[]),
            message(&["a"], &[2.5], &[]),
            message(&["a"], &[], &[1.0]),
            message(&["b"], &[0.0], &[]),
            message(&["a", "b"], &[0.0], &[]),
            message(&["b"], &[], &[3.5]),
        ] {
            assert_eq!(resolve(&t, &data).0, Resolution::Defer);
        }
    }

    #[test]
    fn a_kind_change_takes_effect_in_attached_clones() {
        let t = table();
        let attached = t.clone();
        t.set_kind(0, None);
        assert_eq!(
            resolve(&attached, &message(&["a"], &[0.0], &[])).0,
            Resolution::Defer
        );
        t.set_kind(0, Some(SetpointKind::Velocity));
        let (r, out) = resolve(&attached, &message(&["a"], &[], &[1.0]));
        assert_eq!(
            (r, out),
            (Resolution::Apply, vec![(0, SetpointKind::Velocity, 1.0)])
        );
    }

    fn refusal(t: &JointTable, data: &[u8]) -> Option<String> {
        let mut names = Vec::new();
        let cmd = decode_joint_state(data, &mut names).unwrap();
        let (mut out, mut why) = (Vec::new(), String::new());
        (t.resolve_or_refuse(&cmd, &names, &mut out, &mut why) == Resolution::Refuse).then_some(why)
    }

    #[test]
    fn refuses_what_is_wrong_by_its_structure_in_python_order() {
        let t = table();
        let cases: [(Vec<u8>, Option<&str>); 9] = [
            (message(&[], &[], &[]), Some("no joint names")),
            (
                message(&["a", "b"], &[0.0], &[]),
                Some("position has 1 value(s) for 2 joint name(s) (give one per name, or none)"),
            ),
            (
                message(&["x"], &[0.0], &[]),
                Some("unknown joint 'x' (joints: a, b)"),
            ),
            (
                message(&["a", "a"], &[0.0, 0.1], &[]),
                Some("joint 'a' is named twice"),
            ),
            // Python names the first problem: a's value before x being unknown.
            (message(&["a", "x"], &[9.0, 0.0], &[]), None),
            (
                message(&["a", "x"], &[1.0, 0.0], &[]),
                Some("unknown joint 'x' (joints: a, b)"),
            ),
            // Names Python would quote differently are left to it.
            (message(&["it's"], &[0.0], &[]), None),
            (message(&["a\n"], &[0.0], &[]), None),
            (message(&["a"], &[0.5], &[]), None),
        ];
        for (data, want) in cases {
            assert_eq!(refusal(&t, &data).as_deref(), want);
        }
    }
}
