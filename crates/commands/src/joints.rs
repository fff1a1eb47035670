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

use ether_ros_engine::cia402::status_flags;
use ether_ros_engine::{AxisGate, SetpointKind};
use ether_ros_protocol::cia402::State;
use ether_ros_protocol::emergency;

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
    /// What stopped each joint's axis that it did not ask to stop, as the node saw it: an
    /// index into `STOP_CAUSES` (0: nothing), set by the node's axis watch (`set_cause`).
    causes: Arc<[AtomicU8]>,
}

/// The stop causes the node reports (`ros/node.py`, `_note_stop_cause`), in the words of
/// `axis_blocker`'s `cause`; index 0: none.
pub const STOP_CAUSES: [&str; 4] = [
    "",
    "the command watchdog",
    "a panic",
    "a lapse of the control lease",
];

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
        let causes = joints.iter().map(|_| AtomicU8::new(0)).collect();
        Ok(JointTable {
            joints: joints.into_iter().map(|(j, _)| j).collect(),
            kinds,
            causes,
        })
    }

    /// The kind joint number `joint` takes from now on (None: every command for it goes to
    /// Python). Out-of-range numbers are ignored.
    pub fn set_kind(&self, joint: usize, kind: Option<SetpointKind>) {
        if let Some(k) = self.kinds.get(joint) {
            k.store(kind.map_or(0, |k| k as u8), Ordering::Release);
        }
    }

    /// What stopped joint number `joint`'s axis (one of `STOP_CAUSES`; "" nothing): named in
    /// the answer to a command refused because of it. Err for a cause not in the list.
    pub fn set_cause(&self, joint: usize, cause: &str) -> Result<(), String> {
        let code = STOP_CAUSES
            .iter()
            .position(|c| *c == cause)
            .ok_or_else(|| format!("unknown stop cause {cause:?} (known: {STOP_CAUSES:?})"))?;
        if let Some(c) = self.causes.get(joint) {
            c.store(code as u8, Ordering::Release);
        }
        Ok(())
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

/// Why an axis in the state `gate` cannot follow a setpoint now (false: it can), written to
/// `why` (cleared first) in the words of `ether_ros.master.axis.axis_blocker` with
/// `check_mode=False` (a mode change under way is held for Python by `set_kind`): a fault, a
/// panic of the bus, a blocked restart, a drive not in Operation Enabled; `cause`: what stopped
/// the axis as the node saw it ("" unknown). A halt alone (the
/// command watchdog's stop) does not block: the next command ends it. No allocation beyond
/// `why`'s capacity.
pub fn axis_blocker(gate: AxisGate, panic: bool, cause: &str, why: &mut String) -> bool {
    use std::fmt::Write as _;
    why.clear();
    let state = State::ALL
        .get(gate.state as usize)
        .copied()
        .unwrap_or(State::NotReadyToSwitchOn);
    let name = state.name();
    if matches!(state, State::Fault | State::FaultReactionActive) {
        let code = if gate.error_code != 0 {
            gate.error_code
        } else {
            gate.last_fault_code
        };
        if code != 0 {
            let _ = write!(
                why,
                "in fault (0x{code:04X} {}): reset_fault, then enable",
                emergency::text(code)
            );
        } else {
            why.push_str("in fault (no code): reset_fault, then enable");
        }
        return true;
    }
    if panic {
        why.push_str("the bus is in panic: clear_panic, then enable");
        return true;
    }
    if gate.flags & status_flags::RESTART_BLOCKED != 0 {
        let by = if cause.is_empty() {
            "the watchdog, a panic, a lease lapse or a fault"
        } else {
            cause
        };
        let _ = write!(
            why,
            "restart blocked: stopped by {by} ({name}) and waiting for an explicit enable"
        );
        if gate.last_fault_code != 0 {
            let _ = write!(
                why,
                "; last fault 0x{:04X} {}",
                gate.last_fault_code,
                emergency::text(gate.last_fault_code)
            );
        }
        return true;
    }
    if state != State::OperationEnabled {
        if cause.is_empty() {
            let _ = write!(why, "not enabled ({name}): enable it first");
        } else {
            let _ = write!(why, "disabled by {cause} ({name}): enable it again");
        }
        return true;
    }
    false
}

impl JointTable {
    /// The joint name of engine axis `axis` ("?" when no joint has it).
    pub fn name_of(&self, axis: usize) -> &str {
        self.joints
            .iter()
            .find(|j| j.axis == axis)
            .map_or("?", |j| j.name.as_str())
    }

    /// True, with `why` as Python's answer ("joint 'a' not executed: in fault (...)"), when
    /// one of the axes of `setpoints` cannot follow a setpoint now (`gate_of` its state;
    /// `None`: unknown, which blocks too); then none of them is applied.
    pub fn blocked(
        &self,
        setpoints: &[Setpoint],
        mut gate_of: impl FnMut(usize) -> Option<AxisGate>,
        panic: bool,
        why: &mut String,
    ) -> bool {
        use std::fmt::Write as _;
        for &(axis, _, _) in setpoints {
            let gate = gate_of(axis).unwrap_or_default();
            let cause = self
                .joints
                .iter()
                .position(|j| j.axis == axis)
                .and_then(|j| STOP_CAUSES.get(self.causes[j].load(Ordering::Acquire) as usize))
                .copied()
                .unwrap_or("");
            let mut reason = std::mem::take(why);
            let stop = if gate.published {
                axis_blocker(gate, panic, cause, &mut reason)
            } else {
                reason.clear();
                reason.push_str("the axis has not run a cycle yet");
                true
            };
            if stop {
                why.clear();
                let _ = write!(why, "joint '{}' not executed: {reason}", self.name_of(axis));
                return true;
            }
            *why = reason;
        }
        why.clear();
        false
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

    fn gate(state: State, flags: u16, code: u16) -> AxisGate {
        AxisGate {
            state: state as u8,
            flags,
            error_code: code,
            last_fault_code: code,
            published: true,
        }
    }

    #[test]
    fn a_command_for_an_axis_that_cannot_move_is_refused_with_the_reason() {
        let t = table();
        let sp = [
            (0, SetpointKind::Position, 0.5),
            (1, SetpointKind::Velocity, 1.0),
        ];
        let mut why = String::new();
        let enabled = gate(State::OperationEnabled, status_flags::ENABLE_WANTED, 0);
        // Both can move (a halt alone does not block: the next command ends it).
        let halted = AxisGate {
            flags: status_flags::HALTED,
            ..enabled
        };
        assert!(!t.blocked(&sp, |a| Some([enabled, halted][a]), false, &mut why));
        assert_eq!(why, "");
        // The second is in fault: nothing is applied, and the answer names it and the code.
        let fault = gate(State::Fault, 0, 0x7500);
        assert!(t.blocked(&sp, |a| Some([enabled, fault][a]), false, &mut why));
        assert!(
            why.starts_with("joint 'b' not executed: in fault (0x7500 ")
                && why.ends_with("): reset_fault, then enable"),
            "{why}"
        );
        // Stopped by the watchdog with restart: manual, the drive disabled.
        let stopped = gate(
            State::SwitchOnDisabled,
            status_flags::RESTART_BLOCKED | status_flags::ENABLE_WANTED,
            0,
        );
        assert!(t.blocked(&sp, |a| Some([stopped, enabled][a]), false, &mut why));
        assert_eq!(
            why,
            "joint 'a' not executed: restart blocked: stopped by the watchdog, a panic, a lease \
             lapse or a fault (switch_on_disabled) and waiting for an explicit enable"
        );
        // With the cause the node saw, in its words.
        t.set_cause(0, "the command watchdog").unwrap();
        assert!(t.blocked(&sp, |a| Some([stopped, enabled][a]), false, &mut why));
        assert!(
            why.contains("restart blocked: stopped by the command watchdog (switch_on_disabled)"),
            "{why}"
        );
        let off = gate(State::SwitchOnDisabled, 0, 0);
        assert!(t.blocked(&sp, |a| Some([off, enabled][a]), false, &mut why));
        assert_eq!(
            why,
            "joint 'a' not executed: disabled by the command watchdog (switch_on_disabled): \
             enable it again"
        );
        assert!(t.set_cause(0, "a meteor").is_err());
        t.set_cause(0, "").unwrap();
        // Disabled, in panic, never run, unknown.
        assert!(t.blocked(&sp, |a| Some([off, enabled][a]), false, &mut why));
        assert_eq!(
            why,
            "joint 'a' not executed: not enabled (switch_on_disabled): enable it first"
        );
        assert!(t.blocked(&sp, |_| Some(enabled), true, &mut why));
        assert_eq!(
            why,
            "joint 'a' not executed: the bus is in panic: clear_panic, then enable"
        );
        assert!(t.blocked(&sp, |_| Some(AxisGate::default()), false, &mut why));
        assert!(why.contains("has not run a cycle"), "{why}");
        assert!(t.blocked(&sp, |_| None, false, &mut why));
    }
}
