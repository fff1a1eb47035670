//! CiA 402 drives (IEC 61800-7-201, ETG.6010): the controlword and statusword bits, the device
//! control commands, the power state machine's states as the statusword codes them, the modes
//! of operation (0x6060 values, 0x6502 bits, short names) and the standard objects of an axis.
//!
//! The engine's axis stage, the simulated drive, the configuration checks and the tools all
//! read them from here.

/// Controlword (0x6040) bits.
pub mod cw {
    crate::named_constants! {
        /// Every bit, by name.
        pub const TABLE;
        /// Bit 0: switch on.
        pub const SWITCH_ON: u16 = 1 << 0;
        /// Bit 1: enable voltage.
        pub const ENABLE_VOLTAGE: u16 = 1 << 1;
        /// Bit 2: quick stop (active low: 0 requests a quick stop).
        pub const QUICK_STOP: u16 = 1 << 2;
        /// Bit 3: enable operation.
        pub const ENABLE_OPERATION: u16 = 1 << 3;
        /// Bit 4: mode specific; PP new set-point, HM homing operation start.
        pub const NEW_SETPOINT: u16 = 1 << 4;
        /// Bit 5: PP change set immediately.
        pub const CHANGE_SET_IMMEDIATELY: u16 = 1 << 5;
        /// Bit 6: PP relative target.
        pub const RELATIVE: u16 = 1 << 6;
        /// Bit 7: fault reset (acts on the rising edge).
        pub const FAULT_RESET: u16 = 1 << 7;
        /// Bit 8: halt.
        pub const HALT: u16 = 1 << 8;
    }
}

/// Device control commands: whole controlwords (bits 0..=3; bit 7 is the fault reset).
pub mod command {
    crate::named_constants! {
        /// Every command word, by name.
        pub const TABLE;
        /// Shutdown: to ready to switch on.
        pub const SHUTDOWN: u16 = 0x0006;
        /// Switch on (and, from operation enabled, disable operation).
        pub const SWITCH_ON: u16 = 0x0007;
        /// Enable operation.
        pub const ENABLE_OPERATION: u16 = 0x000F;
        /// Disable voltage.
        pub const DISABLE_VOLTAGE: u16 = 0x0000;
        /// Quick stop.
        pub const QUICK_STOP: u16 = 0x0002;
        /// Fault reset (its rising edge).
        pub const FAULT_RESET: u16 = 0x0080;
    }
}

/// The device control command coded in controlword bits 0..=3 (bit 7, fault reset, acts on its
/// rising edge and is handled apart).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// xxxx xx0x
    DisableVoltage,
    /// xxxx x01x
    QuickStop,
    /// xxxx x110
    Shutdown,
    /// xxxx 0111: "switch on", and in operation enabled "disable operation".
    SwitchOn,
    /// xxxx 1111: "enable operation" (and "switch on" from ready to switch on).
    EnableOperation,
}

impl Command {
    /// The command a controlword gives.
    pub const fn decode(controlword: u16) -> Command {
        if controlword & cw::ENABLE_VOLTAGE == 0 {
            Command::DisableVoltage
        } else if controlword & cw::QUICK_STOP == 0 {
            Command::QuickStop
        } else if controlword & cw::SWITCH_ON == 0 {
            Command::Shutdown
        } else if controlword & cw::ENABLE_OPERATION == 0 {
            Command::SwitchOn
        } else {
            Command::EnableOperation
        }
    }
}

/// Statusword (0x6041) bits.
pub mod sw {
    crate::named_constants! {
        /// Every bit, by name.
        pub const TABLE;
        /// Bit 0: ready to switch on.
        pub const READY_TO_SWITCH_ON: u16 = 1 << 0;
        /// Bit 1: switched on.
        pub const SWITCHED_ON: u16 = 1 << 1;
        /// Bit 2: operation enabled.
        pub const OPERATION_ENABLED: u16 = 1 << 2;
        /// Bit 3: fault.
        pub const FAULT: u16 = 1 << 3;
        /// Bit 4: voltage enabled.
        pub const VOLTAGE_ENABLED: u16 = 1 << 4;
        /// Bit 5: quick stop (active low: 0 while a quick stop is under way).
        pub const QUICK_STOP: u16 = 1 << 5;
        /// Bit 6: switch on disabled.
        pub const SWITCH_ON_DISABLED: u16 = 1 << 6;
        /// Bit 7: warning.
        pub const WARNING: u16 = 1 << 7;
        /// Bit 9: remote (the controlword is processed).
        pub const REMOTE: u16 = 1 << 9;
        /// Bit 10: target reached.
        pub const TARGET_REACHED: u16 = 1 << 10;
        /// Bit 11: internal limit active.
        pub const INTERNAL_LIMIT: u16 = 1 << 11;
        /// Bit 12, mode specific: CSP/CSV/CST the drive follows the command value; PP set-point
        /// acknowledge; PV speed is zero; HM homing attained.
        pub const MODE_12: u16 = 1 << 12;
        /// Bit 13, mode specific: CSP/PP following error; HM homing error.
        pub const MODE_13: u16 = 1 << 13;
        /// Bits 0..=3 and 6: the state coding of most states.
        pub const STATE_MASK: u16 = 0x004F;
        /// Bits 0..=3, 5 and 6: the state coding of the states that differ in bit 5.
        pub const STATE_MASK_QUICK_STOP: u16 = 0x006F;
    }
}

/// The states of the power drive state machine, in the order of the standard's diagram.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum State {
    /// Not ready to switch on.
    NotReadyToSwitchOn = 0,
    /// Switch on disabled.
    SwitchOnDisabled = 1,
    /// Ready to switch on.
    ReadyToSwitchOn = 2,
    /// Switched on.
    SwitchedOn = 3,
    /// Operation enabled.
    OperationEnabled = 4,
    /// Quick stop active.
    QuickStopActive = 5,
    /// Fault reaction active.
    FaultReactionActive = 6,
    /// Fault.
    Fault = 7,
}

impl State {
    /// Every state, in order.
    pub const ALL: [State; 8] = [
        State::NotReadyToSwitchOn,
        State::SwitchOnDisabled,
        State::ReadyToSwitchOn,
        State::SwitchedOn,
        State::OperationEnabled,
        State::QuickStopActive,
        State::FaultReactionActive,
        State::Fault,
    ];

    /// Names as the project's APIs spell them (`operation_enabled`), by state number.
    pub const NAMES: [&'static str; 8] = [
        "not_ready_to_switch_on",
        "switch_on_disabled",
        "ready_to_switch_on",
        "switched_on",
        "operation_enabled",
        "quick_stop_active",
        "fault_reaction_active",
        "fault",
    ];

    /// The state's name.
    pub const fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// Statusword bits 0..=3, 5 and 6 that code the state (bit 5 "quick stop" is active low:
    /// set in the states where no quick stop is under way).
    pub const fn statusword_bits(self) -> u16 {
        match self {
            State::NotReadyToSwitchOn => 0x0000,
            State::SwitchOnDisabled => 0x0040,
            State::ReadyToSwitchOn => 0x0021,
            State::SwitchedOn => 0x0023,
            State::OperationEnabled => 0x0027,
            State::QuickStopActive => 0x0007,
            State::FaultReactionActive => 0x000F,
            State::Fault => 0x0008,
        }
    }

    /// The state a statusword codes (masks 0x4F / 0x6F of the standard), `None` for codings the
    /// standard leaves undefined.
    pub const fn from_statusword(word: u16) -> Option<State> {
        Some(
            match (word & sw::STATE_MASK, word & sw::STATE_MASK_QUICK_STOP) {
                (0x00, _) => State::NotReadyToSwitchOn,
                (0x40, _) => State::SwitchOnDisabled,
                (0x0F, _) => State::FaultReactionActive,
                (0x08, _) => State::Fault,
                (_, 0x21) => State::ReadyToSwitchOn,
                (_, 0x23) => State::SwitchedOn,
                (_, 0x27) => State::OperationEnabled,
                (_, 0x07) => State::QuickStopActive,
                _ => return None,
            },
        )
    }

    /// The state by number (`State::ALL[n]`).
    pub const fn from_number(n: u8) -> Option<State> {
        if (n as usize) < Self::ALL.len() {
            Some(Self::ALL[n as usize])
        } else {
            None
        }
    }

    /// A fault or a fault reaction under way.
    pub const fn is_fault(self) -> bool {
        matches!(self, State::Fault | State::FaultReactionActive)
    }
}

/// Modes of operation (0x6060 / 0x6061 values).
pub mod mode {
    crate::named_constants! {
        /// Every mode code, by name.
        pub const TABLE;
        /// No mode.
        pub const NONE: i8 = 0;
        /// Profile position.
        pub const PP: i8 = 1;
        /// Velocity (frequency converters).
        pub const VL: i8 = 2;
        /// Profile velocity.
        pub const PV: i8 = 3;
        /// Profile torque.
        pub const TQ: i8 = 4;
        /// Homing.
        pub const HM: i8 = 6;
        /// Interpolated position.
        pub const IP: i8 = 7;
        /// Cyclic synchronous position.
        pub const CSP: i8 = 8;
        /// Cyclic synchronous velocity.
        pub const CSV: i8 = 9;
        /// Cyclic synchronous torque.
        pub const CST: i8 = 10;
    }

    /// The bit of a mode in 0x6502 "supported drive modes" (bit 0 PP ... bit 9 CST), `None` for
    /// modes without one.
    pub const fn supported_bit(code: i8) -> Option<u32> {
        if code >= 1 && code <= 10 {
            Some(code as u32 - 1)
        } else {
            None
        }
    }
}

/// The modes the project drives, with their short names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(i8)]
pub enum Mode {
    /// Profile position (`pp`).
    ProfilePosition = mode::PP,
    /// Profile velocity (`pv`).
    ProfileVelocity = mode::PV,
    /// Homing (`hm`).
    Homing = mode::HM,
    /// Cyclic synchronous position (`csp`).
    CyclicPosition = mode::CSP,
    /// Cyclic synchronous velocity (`csv`).
    CyclicVelocity = mode::CSV,
    /// Cyclic synchronous torque (`cst`).
    CyclicTorque = mode::CST,
}

impl Mode {
    /// Every mode, in the order of their codes.
    pub const ALL: [Mode; 6] = [
        Mode::ProfilePosition,
        Mode::ProfileVelocity,
        Mode::Homing,
        Mode::CyclicPosition,
        Mode::CyclicVelocity,
        Mode::CyclicTorque,
    ];

    /// The 0x6060 value.
    pub const fn code(self) -> i8 {
        self as i8
    }

    /// The short name (`csp`).
    pub const fn name(self) -> &'static str {
        match self {
            Mode::ProfilePosition => "pp",
            Mode::ProfileVelocity => "pv",
            Mode::Homing => "hm",
            Mode::CyclicPosition => "csp",
            Mode::CyclicVelocity => "csv",
            Mode::CyclicTorque => "cst",
        }
    }

    /// The mode with 0x6060 value `code`.
    pub fn from_code(code: i8) -> Option<Mode> {
        Self::ALL.into_iter().find(|m| m.code() == code)
    }

    /// The mode with short name `name`.
    pub fn from_name(name: &str) -> Option<Mode> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// The bit in 0x6502.
    pub const fn supported_bit(self) -> u32 {
        self as u32 - 1
    }
}

/// The standard objects of axis 0; axis n has them at `index + n·AXIS_OFFSET` (ETG.6010).
pub mod object {
    crate::named_constants! {
        /// Every object index, by name.
        pub const TABLE;
        /// Index distance between the axes of a multi-axis drive.
        pub const AXIS_OFFSET: u16 = 0x0800;
        /// Most axes a drive may have (ETG.6010).
        pub const MAX_AXES: u16 = 8;
        /// Error code (u16).
        pub const ERROR_CODE: u16 = 0x603F;
        /// Controlword (u16).
        pub const CONTROLWORD: u16 = 0x6040;
        /// Statusword (u16).
        pub const STATUSWORD: u16 = 0x6041;
        /// Quick stop option code (i16).
        pub const QUICK_STOP_OPTION: u16 = 0x605A;
        /// Modes of operation (i8).
        pub const MODES_OF_OPERATION: u16 = 0x6060;
        /// Modes of operation display (i8).
        pub const MODES_OF_OPERATION_DISPLAY: u16 = 0x6061;
        /// Position actual value (i32).
        pub const POSITION_ACTUAL: u16 = 0x6064;
        /// Following error window (u32).
        pub const FOLLOWING_ERROR_WINDOW: u16 = 0x6065;
        /// Following error time out (u16, ms).
        pub const FOLLOWING_ERROR_TIMEOUT: u16 = 0x6066;
        /// Position window (u32).
        pub const POSITION_WINDOW: u16 = 0x6067;
        /// Velocity window (u16).
        pub const VELOCITY_WINDOW: u16 = 0x606D;
        /// Max torque (u16, per mille of the motor rated torque).
        pub const MAX_TORQUE: u16 = 0x6072;
        /// Motor rated torque (u32, mN·m).
        pub const MOTOR_RATED_TORQUE: u16 = 0x6076;
        /// Home offset (i32).
        pub const HOME_OFFSET: u16 = 0x607C;
        /// Max motor speed (u32, rpm).
        pub const MAX_MOTOR_SPEED: u16 = 0x6080;
        /// Quick stop deceleration (u32).
        pub const QUICK_STOP_DECELERATION: u16 = 0x6085;
        /// Position encoder resolution (record: 1 increments, 2 motor revolutions).
        pub const POSITION_ENCODER_RESOLUTION: u16 = 0x608F;
        /// Gear ratio (record: 1 motor revolutions, 2 shaft revolutions).
        pub const GEAR_RATIO: u16 = 0x6091;
        /// Homing speeds (record: 1 speed during search for switch, 2 for zero).
        pub const HOMING_SPEEDS: u16 = 0x6099;
        /// Homing acceleration (u32).
        pub const HOMING_ACCELERATION: u16 = 0x609A;
        /// Velocity offset (i32; velocity feed-forward in csp/csv).
        pub const VELOCITY_OFFSET: u16 = 0x60B1;
        /// Torque offset (i16; torque feed-forward in csp/csv/cst).
        pub const TORQUE_OFFSET: u16 = 0x60B2;
        /// Touch probe function (u16).
        pub const TOUCH_PROBE_FUNCTION: u16 = 0x60B8;
        /// Touch probe status (u16).
        pub const TOUCH_PROBE_STATUS: u16 = 0x60B9;
        /// Touch probe 1 position, positive edge (i32).
        pub const TOUCH_PROBE_1_POSITIVE: u16 = 0x60BA;
        /// Touch probe 1 position, negative edge (i32).
        pub const TOUCH_PROBE_1_NEGATIVE: u16 = 0x60BB;
        /// Supported homing methods (array of i8).
        pub const SUPPORTED_HOMING_METHODS: u16 = 0x60E3;
        /// Digital inputs (u32).
        pub const DIGITAL_INPUTS: u16 = 0x60FD;
        /// Digital outputs (record: 1 physical outputs u32, 2 bit mask u32).
        pub const DIGITAL_OUTPUTS: u16 = 0x60FE;
        /// Velocity actual value (i32).
        pub const VELOCITY_ACTUAL: u16 = 0x606C;
        /// Target torque (i16).
        pub const TARGET_TORQUE: u16 = 0x6071;
        /// Torque actual value (i16).
        pub const TORQUE_ACTUAL: u16 = 0x6077;
        /// Target position (i32).
        pub const TARGET_POSITION: u16 = 0x607A;
        /// Software position limit (record: 1 min, 2 max).
        pub const SOFTWARE_POSITION_LIMIT: u16 = 0x607D;
        /// Profile velocity (u32).
        pub const PROFILE_VELOCITY: u16 = 0x6081;
        /// Profile acceleration (u32).
        pub const PROFILE_ACCELERATION: u16 = 0x6083;
        /// Profile deceleration (u32).
        pub const PROFILE_DECELERATION: u16 = 0x6084;
        /// Homing method (i8).
        pub const HOMING_METHOD: u16 = 0x6098;
        /// Interpolation time period (record: 1 value, 2 index).
        pub const INTERPOLATION_TIME_PERIOD: u16 = 0x60C2;
        /// Following error actual value (i32).
        pub const FOLLOWING_ERROR_ACTUAL: u16 = 0x60F4;
        /// Target velocity (i32).
        pub const TARGET_VELOCITY: u16 = 0x60FF;
        /// Supported drive modes (u32).
        pub const SUPPORTED_MODES: u16 = 0x6502;
    }

    /// The index of object `index` (given for axis 0) on axis `axis`.
    pub const fn of_axis(index: u16, axis: u16) -> u16 {
        index + axis * AXIS_OFFSET
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_state_decodes_from_its_own_bits_whatever_else_is_set() {
        for s in State::ALL {
            assert_eq!(State::from_statusword(s.statusword_bits()), Some(s));
            // Bits outside the coding (4, 7, 9..=15) do not change the state.
            assert_eq!(
                State::from_statusword(s.statusword_bits() | 0xFF90),
                Some(s),
                "{s:?}"
            );
            assert_eq!(State::from_number(s as u8), Some(s));
        }
        assert_eq!(
            State::from_statusword(0x0060),
            Some(State::SwitchOnDisabled)
        );
        assert_eq!(State::from_statusword(0x0028), Some(State::Fault));
        assert_eq!(State::from_statusword(0x0001), None);
        assert_eq!(State::OperationEnabled.name(), "operation_enabled");
    }

    #[test]
    fn commands_and_modes() {
        assert_eq!(Command::decode(command::SHUTDOWN), Command::Shutdown);
        assert_eq!(Command::decode(command::SWITCH_ON), Command::SwitchOn);
        assert_eq!(
            Command::decode(command::ENABLE_OPERATION),
            Command::EnableOperation
        );
        assert_eq!(Command::decode(command::QUICK_STOP), Command::QuickStop);
        assert_eq!(
            Command::decode(command::DISABLE_VOLTAGE | 0x0F0D),
            Command::DisableVoltage
        );
        for m in Mode::ALL {
            assert_eq!(Mode::from_code(m.code()), Some(m));
            assert_eq!(Mode::from_name(m.name()), Some(m));
            assert_eq!(mode::supported_bit(m.code()), Some(m.supported_bit()));
        }
        // 0x6502 bits of servo_drive.xml's default 0x3A5: PP, PV, HM, CSP, CSV, CST.
        let bits: u32 = Mode::ALL.iter().map(|m| 1 << m.supported_bit()).sum();
        assert_eq!(bits, 0x3A5);
        assert_eq!(object::of_axis(object::CONTROLWORD, 1), 0x6840);
    }
}
