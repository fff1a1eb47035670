"""ROS 2 message definitions written into recordings (MCAP schemas).

A recording must be readable without a ROS installation and without this repository, so each
schema carries its full definition text, dependencies included, in the ``ros2msg`` format that
MCAP readers (Foxglove, ``ros2 bag``, mcap_ros2) understand. The ``ether_ros_msgs`` texts are the
ones in ``interfaces/ether_ros_msgs/msg`` (a unit test keeps the two in step).

``ether_ros_msgs/CycleTimingBatch`` exists only in recordings: the node publishes statistics, not
every cycle, but the timing histograms need every cycle, so the recorder stores them in batches.
"""

from __future__ import annotations

TIME = """int32 sec
uint32 nanosec
"""

HEADER = """builtin_interfaces/Time stamp
string frame_id
"""

VARIABLE_INFO = """\
# One process variable of a slave, as mapped by the ESI/PDO assignment.
string name          # variable name (ESI entry name)
string type          # ESI data type: BOOL, SINT, INT, DINT, USINT, UINT, UDINT, REAL, ...
uint16 index         # object dictionary index
uint8 subindex       # object dictionary subindex
uint16 bit_length
float64 minimum      # smallest value the type (or the ESI) allows
float64 maximum      # largest value the type (or the ESI) allows
"""

SLAVE_LAYOUT = """\
# The decoded process data layout of one slave: names and types of the values in SlaveValues.
string slave              # configured slave name
uint16 position           # position on the bus
string device             # ESI device type
string group              # slave group ("default": exchanged every bus cycle)
uint32 group_cycle_us     # the group's cycle: a whole multiple of the bus cycle
VariableInfo[] inputs     # order of SlaveValues.values on the inputs topic
VariableInfo[] outputs    # order of SlaveValues.values on the outputs topics
"""

BUS_LAYOUT = """\
# Every slave's layout, published once per configure on a transient-local (latched) topic.
std_msgs/Header header
string bus                 # bus name from the configuration
uint32 cycle_us            # cycle period
SlaveLayout[] slaves
"""

SLAVE_VALUES = """\
# Decoded process values of one slave in one cycle, in the order given by its SlaveLayout.
# Integers up to 2^53 are exact in float64; BOOL is 0.0 / 1.0.
std_msgs/Header header
string slave
uint16 position
uint64 cycle
float64[] values
# True when these are not fresh inputs: no reply to the slave's frame came back whole (every
# working counter as expected) within two of its periods, or the bus is down; the values are
# then the last ones received. Always false for outputs.
bool stale
"""

PDO_RAW = """\
# The whole process image of one cycle, as exchanged on the wire (the thesis's /pdo_raw).
# Published every `ros.raw_decimation` cycles.
std_msgs/Header header
uint64 cycle                      # cycle counter of the real-time loop
uint16 working_counter            # working counter the frame came back with
uint16 expected_working_counter   # working counter of a healthy bus
uint8[] pdo_in                    # input image (slaves -> master)
uint8[] pdo_out                   # output image (master -> slaves) sent in that cycle
"""

CYCLE_TIMING_BATCH = """\
# Per-cycle timing of the real-time loop, a batch of consecutive cycles (recordings only).
std_msgs/Header header
uint64[] cycle
uint64[] t_wake_ns          # actual wake-up, CLOCK_MONOTONIC
int64[] wake_latency_ns     # actual minus planned wake-up
uint32[] exec_ns            # wake-up to cyclic frame sent
uint32[] period_ns          # time since the previous wake-up
uint32[] rtt_ns             # round trip of the cyclic reply (0: none)
uint16[] working_counter
uint16[] flags              # LOST 1, LATE 2, WKC_ERROR 4, PANIC 8, WATCHDOG 16, ...
int32[] dc_diff_ns          # distributed-clock difference
"""

JOINT_STATE = """std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
"""

KEY_VALUE = """string key
string value
"""

DIAGNOSTIC_STATUS = """byte OK=0
byte WARN=1
byte ERROR=2
byte STALE=3
byte level
string name
string message
string hardware_id
KeyValue[] values
"""

DIAGNOSTIC_ARRAY = """std_msgs/Header header
diagnostic_msgs/DiagnosticStatus[] status
"""

_SEP = "=" * 80


def _bundle(main: str, deps: list[tuple[str, str]]) -> str:
    parts = [main.rstrip("\n")]
    for name, text in deps:
        parts.append(f"{_SEP}\nMSG: {name}\n{text.rstrip(chr(10))}")
    return "\n".join(parts) + "\n"


_HEADER_DEPS = [("std_msgs/Header", HEADER), ("builtin_interfaces/Time", TIME)]

# Full definitions by type name, ready for ``Writer.register_msgdef``.
DEFINITIONS: dict[str, str] = {
    "ether_ros_msgs/msg/BusLayout": _bundle(
        BUS_LAYOUT,
        [
            *_HEADER_DEPS,
            ("ether_ros_msgs/SlaveLayout", SLAVE_LAYOUT),
            ("ether_ros_msgs/VariableInfo", VARIABLE_INFO),
        ],
    ),
    "ether_ros_msgs/msg/SlaveValues": _bundle(SLAVE_VALUES, _HEADER_DEPS),
    "ether_ros_msgs/msg/PdoRaw": _bundle(PDO_RAW, _HEADER_DEPS),
    "ether_ros_msgs/msg/CycleTimingBatch": _bundle(CYCLE_TIMING_BATCH, _HEADER_DEPS),
    "sensor_msgs/msg/JointState": _bundle(JOINT_STATE, _HEADER_DEPS),
    "diagnostic_msgs/msg/DiagnosticArray": _bundle(
        DIAGNOSTIC_ARRAY,
        [
            *_HEADER_DEPS,
            ("diagnostic_msgs/DiagnosticStatus", DIAGNOSTIC_STATUS),
            ("diagnostic_msgs/KeyValue", KEY_VALUE),
        ],
    ),
}

# The texts that must equal interfaces/ether_ros_msgs/msg/<name>.msg.
INTERFACE_TEXTS = {
    "BusLayout": BUS_LAYOUT,
    "SlaveLayout": SLAVE_LAYOUT,
    "VariableInfo": VARIABLE_INFO,
    "SlaveValues": SLAVE_VALUES,
    "PdoRaw": PDO_RAW,
}
