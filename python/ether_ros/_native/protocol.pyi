"""Type stub of ``ether_ros._native.protocol`` (crates/py/src/protocol_bindings.rs): the EtherCAT
facts of the protocol crate (crates/protocol). The namespaces below are built at import from the
crate's tables; ``tests/unit/test_protocol.py`` checks this stub against the module and
``scripts/gen_protocol_stub.py`` rewrites the namespace part from it."""

from collections.abc import Sequence
from typing import Final, Self, final

__all__ = [
    "AL_STATES",
    "AL_STATUS_TEXTS",
    "CIA402_MODES",
    "CIA402_STATES",
    "EMERGENCY_TEXTS",
    "FOE_ERROR_TEXTS",
    "PORT_ORDER",
    "SDO_ABORT_TEXTS",
    "AreaDecoder",
    "ValueCheckError",
    "__doc__",
    "al",
    "al_code",
    "al_state_name",
    "al_status_text",
    "auto_increment_address",
    "check_value",
    "cia402",
    "cia402_state",
    "cmd",
    "coe",
    "coe_header",
    "config_type",
    "cw",
    "data_types",
    "dc",
    "dc_time_difference",
    "decode_int",
    "dl",
    "dtype",
    "emergency_text",
    "encode_int",
    "esc_config",
    "esi_type",
    "esi_type_name",
    "features",
    "fixed_address",
    "fmmu",
    "fmmu_record",
    "foe",
    "foe_error",
    "foe_error_text",
    "foe_message",
    "format_address",
    "format_pdo_address",
    "forwarding_ports",
    "frame",
    "mailbox",
    "mailbox_error",
    "mailbox_error_text",
    "mailbox_header",
    "mailbox_type_name",
    "mode",
    "object_code_name",
    "open_ports",
    "parse_address",
    "parse_fmmu_record",
    "parse_foe",
    "parse_index",
    "parse_mailbox_header",
    "parse_pdo_address",
    "parse_sdo_header",
    "parse_sdo_segment",
    "parse_sii_dcs",
    "parse_sii_pdos",
    "parse_sii_syncms",
    "parse_sm_record",
    "parse_subindex",
    "port_desc",
    "reg",
    "sdo_abort",
    "sdo_abort_message",
    "sdo_abort_text",
    "sdo_expedited",
    "sdo_initiate",
    "sdo_segment",
    "sdo_toggle_message",
    "sii",
    "sii_categories",
    "sii_category",
    "sii_category_bytes",
    "sii_checksum",
    "sii_dc_record",
    "sii_fmmu",
    "sii_general",
    "sii_list_complete",
    "sii_pdo",
    "sii_pdo_entry_record",
    "sii_pdo_record",
    "sii_syncm",
    "sii_syncm_record",
    "sii_word",
    "sm",
    "sm_record",
    "soe",
    "soe_error",
    "sw",
    "value_range",
]

PORT_ORDER: tuple[int, int, int, int]
AL_STATES: tuple[int, ...]
CIA402_STATES: tuple[str, ...]
CIA402_MODES: tuple[tuple[str, int, int], ...]
AL_STATUS_TEXTS: dict[int, str]
SDO_ABORT_TEXTS: dict[int, str]
EMERGENCY_TEXTS: dict[int, str]
FOE_ERROR_TEXTS: dict[int, str]

class ValueCheckError(ValueError):
    reason: str
    minimum: float | None
    maximum: float | None

@final
class AreaDecoder:
    def __new__(cls, fields: Sequence[tuple[int, int, str]]) -> Self: ...
    def __len__(self) -> int: ...
    def decode(self, area: bytes) -> list[float]: ...

def al_state_name(state: int) -> str | None: ...
def al_status_text(code: int) -> str: ...
def sdo_abort_text(code: int) -> str: ...
def mailbox_error_text(code: int) -> str: ...
def mailbox_type_name(mbx_type: int) -> str | None: ...
def emergency_text(code: int) -> str: ...
def mailbox_header(length: int, mbx_type: int, counter: int, address: int = 0) -> bytes: ...
def parse_mailbox_header(data: bytes) -> tuple[int, int, int, int, int] | None: ...
def object_code_name(code: int) -> str | None: ...
def sii_checksum(data: bytes) -> int: ...
def parse_address(text: str) -> tuple[int, int] | None: ...
def format_address(index: int, subindex: int) -> str: ...
def parse_index(text: str) -> int: ...
def parse_subindex(text: str) -> int: ...
def parse_pdo_address(text: str) -> tuple[int | None, int, int] | None: ...
def format_pdo_address(pdo: int, index: int, subindex: int) -> str: ...
def data_types() -> list[tuple[int, str, int, str]]: ...
def esi_type(name: str) -> int | None: ...
def config_type(name: str) -> int | None: ...
def esi_type_name(code: int) -> str | None: ...
def value_range(kind_name: str, bits: int) -> tuple[int, int] | tuple[float, float]: ...
def encode_int(kind_name: str, bits: int, value: int) -> int: ...
def decode_int(kind_name: str, bits: int, raw: int) -> int: ...
def check_value(kind_name: str, value: float, minimum: float, maximum: float) -> None: ...
def auto_increment_address(position: int, offset: int) -> int: ...
def fixed_address(station: int, offset: int) -> int: ...
def forwarding_ports(mask: int) -> list[int]: ...
def open_ports(dl_status: int) -> int: ...
def cia402_state(statusword: int) -> str | None: ...
def dc_time_difference(raw: int) -> int: ...
def sm_record(start: int, length: int, control: int, enable: bool = True) -> bytes: ...
def parse_sm_record(data: bytes) -> tuple[int, int, int, int, int, int] | None: ...
def fmmu_record(
    logical_start: int,
    length: int,
    physical_start: int,
    kind: int,
    logical_start_bit: int = 0,
    logical_stop_bit: int = 7,
    physical_start_bit: int = 0,
    enable: bool = True,
) -> bytes: ...
def parse_fmmu_record(data: bytes) -> tuple[int, int, int, int, int, int, int, int] | None: ...
def sii_categories(image: bytes) -> list[tuple[int, int, bytes]]: ...
def sii_category_bytes(kind: int, data: bytes) -> bytes: ...
def sii_list_complete(image: bytes, max_bytes: int) -> bool: ...
def sii_syncm_record(start: int, length: int, control: int, enable: int, kind: int) -> bytes: ...
def parse_sii_syncms(data: bytes) -> list[tuple[int, int, int, int, int, int]]: ...
def sii_pdo_record(index: int, entries: int, sync_manager: int, name: int, flags: int) -> bytes: ...
def sii_pdo_entry_record(
    index: int, subindex: int, name: int, data_type: int, bit_length: int
) -> bytes: ...
def parse_sii_pdos(
    data: bytes,
) -> tuple[list[tuple[int, int, int, int, list[tuple[int, int, int, int, int]]]], int | None]: ...
def sii_dc_record(
    cycle_time_sync0: int,
    shift_time_sync0: int,
    shift_time_sync1: int,
    sync1_cycle_factor: int,
    assign_activate: int,
    sync0_cycle_factor: int,
    name: int,
    description: int,
) -> bytes: ...
def parse_sii_dcs(data: bytes) -> list[tuple[int, int, int, int, int, int, int, int]]: ...
def coe_header(service: int) -> bytes: ...
def sdo_segment(service: int, specifier: int, toggle: bool, last: bool, data: bytes) -> bytes: ...
def sdo_toggle_message(service: int, specifier: int, toggle: bool) -> bytes: ...
def parse_sdo_segment(message: bytes) -> tuple[int, int, bool, bool, bytes] | None: ...
def foe_message(opcode: int, field: int, body: bytes = ...) -> bytes: ...
def parse_foe(data: bytes) -> tuple[int, int, bytes]: ...
def foe_error_text(code: int) -> str: ...
def sdo_initiate(
    service: int,
    specifier: int,
    index: int,
    subindex: int,
    complete_access: bool = False,
    size: int | None = None,
) -> bytes: ...
def sdo_expedited(
    service: int,
    specifier: int,
    index: int,
    subindex: int,
    data: bytes,
    complete_access: bool = False,
) -> bytes: ...
def sdo_abort_message(service: int, index: int, subindex: int, code: int) -> bytes: ...
def parse_sdo_header(
    message: bytes,
) -> tuple[int, int, bool, int, int, bytes | None, int] | None: ...

# ---- namespaces (generated by scripts/gen_protocol_stub.py) ----

class frame:
    """Frame and datagram layout."""

    ETHERTYPE: Final[int]
    ETH_HEADER_LEN: Final[int]
    ECAT_HEADER_LEN: Final[int]
    DATAGRAM_HEADER_LEN: Final[int]
    WKC_LEN: Final[int]
    MIN_FRAME_LEN: Final[int]
    MAX_PAYLOAD: Final[int]
    MAX_FRAME_LEN: Final[int]
    MAX_DATAGRAM_DATA: Final[int]
    ECAT_TYPE_DLPDU: Final[int]

class cmd:
    """Datagram command codes."""

    NOP: Final[int]
    APRD: Final[int]
    APWR: Final[int]
    APRW: Final[int]
    FPRD: Final[int]
    FPWR: Final[int]
    FPRW: Final[int]
    BRD: Final[int]
    BWR: Final[int]
    BRW: Final[int]
    LRD: Final[int]
    LWR: Final[int]
    LRW: Final[int]
    ARMW: Final[int]
    FRMW: Final[int]

class reg:
    """ESC register addresses."""

    TYPE: Final[int]
    REVISION: Final[int]
    BUILD: Final[int]
    FMMU_COUNT: Final[int]
    SM_COUNT: Final[int]
    RAM_SIZE: Final[int]
    PORT_DESC: Final[int]
    FEATURES: Final[int]
    STATION_ADDRESS: Final[int]
    STATION_ALIAS: Final[int]
    DL_CONTROL: Final[int]
    DL_CONTROL_LOOP: Final[int]
    DL_CONTROL_ALIAS: Final[int]
    DL_STATUS: Final[int]
    AL_CONTROL: Final[int]
    AL_STATUS: Final[int]
    AL_STATUS_CODE: Final[int]
    PDI_CONTROL: Final[int]
    ESC_CONFIG: Final[int]
    ECAT_EVENT_MASK: Final[int]
    AL_EVENT_REQUEST: Final[int]
    RX_ERROR_COUNTER: Final[int]
    LOST_LINK_COUNTER: Final[int]
    WATCHDOG_DIVIDER: Final[int]
    WATCHDOG_TIME_PDI: Final[int]
    WATCHDOG_TIME_PD: Final[int]
    WATCHDOG_STATUS_PD: Final[int]
    WATCHDOG_COUNTER_PD: Final[int]
    WATCHDOG_COUNTER_PDI: Final[int]
    SII_CONFIG: Final[int]
    SII_PDI_ACCESS: Final[int]
    SII_CONTROL: Final[int]
    SII_ADDRESS: Final[int]
    SII_DATA: Final[int]
    MII_MANAGEMENT: Final[int]
    FMMU0: Final[int]
    FMMU_LEN: Final[int]
    MAX_FMMUS: Final[int]
    SM0: Final[int]
    SM_LEN: Final[int]
    MAX_SMS: Final[int]
    DC_RECEIVE_TIME_PORT0: Final[int]
    DC_SYSTEM_TIME: Final[int]
    DC_RECEIVE_TIME_PU: Final[int]
    DC_SYSTEM_TIME_OFFSET: Final[int]
    DC_SYSTEM_TIME_DELAY: Final[int]
    DC_SYSTEM_TIME_DIFF: Final[int]
    DC_SPEED_COUNTER_START: Final[int]
    DC_SPEED_COUNTER_DIFF: Final[int]
    DC_FILTER_DEPTH: Final[int]
    DC_CYCLIC_UNIT_CONTROL: Final[int]
    DC_ACTIVATION: Final[int]
    DC_SYNC0_STATUS: Final[int]
    DC_START_TIME: Final[int]
    DC_SYNC0_CYCLE: Final[int]
    DC_SYNC1_CYCLE: Final[int]
    DIGITAL_OUTPUTS: Final[int]
    DIGITAL_OUTPUTS_LEN: Final[int]
    PDRAM: Final[int]

class features:
    """ESC features (0x0008) bits."""

    FMMU_BYTE_ORIENTED: Final[int]
    DC: Final[int]
    DC_64BIT: Final[int]
    LOW_JITTER_EBUS: Final[int]
    ENHANCED_LINK_EBUS: Final[int]
    ENHANCED_LINK_MII: Final[int]
    SEPARATE_FCS_ERRORS: Final[int]
    ENHANCED_DC_SYNC: Final[int]
    LRW_NOT_SUPPORTED: Final[int]
    READ_WRITE_NOT_SUPPORTED: Final[int]
    FIXED_FMMU_SM: Final[int]

class port_desc:
    """Port descriptor (0x0007) values."""

    NOT_IMPLEMENTED: Final[int]
    NOT_CONFIGURED: Final[int]
    EBUS: Final[int]
    MII: Final[int]

class dl:
    """DL control and status bits."""

    STATUS_PDI_OPERATIONAL: Final[int]
    STATUS_PDI_WATCHDOG: Final[int]
    STATUS_ENHANCED_LINK: Final[int]
    STATUS_LINK_PORT0: Final[int]
    STATUS_LOOP_PORT0: Final[int]
    STATUS_COMM_PORT0: Final[int]
    LOOP_AUTO: Final[int]
    LOOP_AUTO_CLOSE: Final[int]
    LOOP_OPEN: Final[int]
    LOOP_CLOSED: Final[int]

class sm:
    """SyncManager register offsets and bits."""

    START: Final[int]
    LENGTH: Final[int]
    CONTROL: Final[int]
    STATUS: Final[int]
    ACTIVATE: Final[int]
    PDI_CONTROL: Final[int]
    MODE_BUFFERED: Final[int]
    MODE_MAILBOX: Final[int]
    MODE_MASK: Final[int]
    DIR_READ: Final[int]
    DIR_WRITE: Final[int]
    DIR_MASK: Final[int]
    ECAT_EVENT: Final[int]
    PDI_EVENT: Final[int]
    WATCHDOG: Final[int]
    STATUS_MAILBOX_FULL: Final[int]
    STATUS_BUFFER_MASK: Final[int]
    ACTIVATE_ENABLE: Final[int]
    REPEAT: Final[int]
    PDI_DEACTIVATE: Final[int]

class fmmu:
    """FMMU register offsets and bits."""

    LOGICAL_START: Final[int]
    LENGTH: Final[int]
    LOGICAL_START_BIT: Final[int]
    LOGICAL_STOP_BIT: Final[int]
    PHYSICAL_START: Final[int]
    PHYSICAL_START_BIT: Final[int]
    TYPE: Final[int]
    ACTIVATE: Final[int]
    READ: Final[int]
    WRITE: Final[int]
    ACTIVATE_ENABLE: Final[int]

class dc:
    """Distributed clock bits."""

    ACTIVATE_CYCLIC: Final[int]
    ACTIVATE_SYNC0: Final[int]
    ACTIVATE_SYNC1: Final[int]
    DIFF_SIGN: Final[int]

class esc_config:
    """ESC configuration (0x0141) bits."""

    DEVICE_EMULATION: Final[int]

class al:
    """AL states and control/status bits."""

    INIT: Final[int]
    PREOP: Final[int]
    BOOT: Final[int]
    SAFEOP: Final[int]
    OP: Final[int]
    STATE_MASK: Final[int]
    ERROR: Final[int]
    ID_REQUEST: Final[int]

class al_code:
    """AL status codes."""

    NO_ERROR: Final[int]
    UNSPECIFIED: Final[int]
    NO_MEMORY: Final[int]
    INVALID_DEVICE_SETUP: Final[int]
    INVALID_REQUESTED_STATE: Final[int]
    UNKNOWN_REQUESTED_STATE: Final[int]
    BOOTSTRAP_NOT_SUPPORTED: Final[int]
    NO_VALID_FIRMWARE: Final[int]
    INVALID_BOOT_MAILBOX_CONFIG: Final[int]
    INVALID_MAILBOX_CONFIG: Final[int]
    INVALID_SM_CONFIG: Final[int]
    NO_VALID_INPUTS: Final[int]
    NO_VALID_OUTPUTS: Final[int]
    SYNCHRONIZATION_ERROR: Final[int]
    SM_WATCHDOG: Final[int]
    INVALID_SM_TYPES: Final[int]
    INVALID_OUTPUT_CONFIG: Final[int]
    INVALID_INPUT_CONFIG: Final[int]
    INVALID_WATCHDOG_CONFIG: Final[int]
    SLAVE_NEEDS_COLD_START: Final[int]
    SLAVE_NEEDS_INIT: Final[int]
    SLAVE_NEEDS_PREOP: Final[int]
    SLAVE_NEEDS_SAFEOP: Final[int]
    INVALID_INPUT_MAPPING: Final[int]
    INVALID_OUTPUT_MAPPING: Final[int]
    INCONSISTENT_SETTINGS: Final[int]
    FREERUN_NOT_SUPPORTED: Final[int]
    SYNCMODE_NOT_SUPPORTED: Final[int]
    FREERUN_NEEDS_3_BUFFER: Final[int]
    BACKGROUND_WATCHDOG: Final[int]
    NO_VALID_INPUTS_AND_OUTPUTS: Final[int]
    FATAL_SYNC_ERROR: Final[int]
    NO_SYNC_ERROR: Final[int]
    CYCLE_TIME_TOO_SMALL: Final[int]
    INVALID_DC_SYNC_CONFIG: Final[int]
    INVALID_DC_LATCH_CONFIG: Final[int]
    PLL_ERROR: Final[int]
    DC_SYNC_IO_ERROR: Final[int]
    DC_SYNC_TIMEOUT: Final[int]
    DC_INVALID_SYNC_CYCLE_TIME: Final[int]
    DC_SYNC0_CYCLE_TIME: Final[int]
    DC_SYNC1_CYCLE_TIME: Final[int]
    MBX_AOE: Final[int]
    MBX_EOE: Final[int]
    MBX_COE: Final[int]
    MBX_FOE: Final[int]
    MBX_SOE: Final[int]
    MBX_VOE: Final[int]
    EEPROM_NO_ACCESS: Final[int]
    EEPROM_ERROR: Final[int]
    EXTERNAL_HARDWARE_NOT_READY: Final[int]
    SLAVE_RESTARTED_LOCALLY: Final[int]
    DEVICE_ID_UPDATED: Final[int]
    MODULE_ID_MISMATCH: Final[int]
    APPLICATION_CONTROLLER: Final[int]

class sii:
    """SII control/status bits and commands."""

    CONFIG_PDI: Final[int]
    CONFIG_RESET_PDI_ACCESS: Final[int]
    WRITE_ENABLE: Final[int]
    EMULATION: Final[int]
    READ_8_BYTES: Final[int]
    TWO_ADDRESS_BYTES: Final[int]
    CMD_READ: Final[int]
    CMD_WRITE: Final[int]
    CMD_RELOAD: Final[int]
    CMD_MASK: Final[int]
    CHECKSUM_ERROR: Final[int]
    NOT_LOADED: Final[int]
    COMMAND_ERROR: Final[int]
    WRITE_ERROR: Final[int]
    BUSY: Final[int]
    ERROR_MASK: Final[int]
    COMMAND_ERRORS: Final[int]

class sii_word:
    """SII header word addresses."""

    PDI_CONTROL: Final[int]
    PDI_CONFIG: Final[int]
    SYNC_IMPULSE_LEN: Final[int]
    PDI_CONFIG_2: Final[int]
    CONFIGURED_ALIAS: Final[int]
    CHECKSUM: Final[int]
    VENDOR_ID: Final[int]
    PRODUCT_CODE: Final[int]
    REVISION: Final[int]
    SERIAL: Final[int]
    BOOT_RX_MBX_OFFSET: Final[int]
    BOOT_RX_MBX_SIZE: Final[int]
    BOOT_TX_MBX_OFFSET: Final[int]
    BOOT_TX_MBX_SIZE: Final[int]
    STD_RX_MBX_OFFSET: Final[int]
    STD_RX_MBX_SIZE: Final[int]
    STD_TX_MBX_OFFSET: Final[int]
    STD_TX_MBX_SIZE: Final[int]
    MBX_PROTOCOL: Final[int]
    SIZE: Final[int]
    VERSION: Final[int]
    FIRST_CATEGORY: Final[int]
    CHECKSUM_COVERS: Final[int]

class sii_category:
    """SII category types."""

    NOP: Final[int]
    STRINGS: Final[int]
    DATA_TYPES: Final[int]
    GENERAL: Final[int]
    FMMU: Final[int]
    SYNCM: Final[int]
    TXPDO: Final[int]
    RXPDO: Final[int]
    DC: Final[int]
    END: Final[int]

class sii_syncm:
    """SII SyncM category: SyncManager types and enable bits."""

    TYPE_UNUSED: Final[int]
    TYPE_MBOX_OUT: Final[int]
    TYPE_MBOX_IN: Final[int]
    TYPE_OUTPUTS: Final[int]
    TYPE_INPUTS: Final[int]
    ENABLE: Final[int]
    FIXED_CONTENT: Final[int]
    VIRTUAL: Final[int]
    OP_ONLY: Final[int]
    RECORD_LEN: Final[int]

class sii_general:
    """SII General category: byte offsets, CoE details, flags, port types."""

    GROUP: Final[int]
    IMAGE: Final[int]
    ORDER: Final[int]
    NAME: Final[int]
    COE_DETAILS: Final[int]
    FOE_DETAILS: Final[int]
    EOE_DETAILS: Final[int]
    FLAGS: Final[int]
    CURRENT_ON_EBUS: Final[int]
    GROUP_COPY: Final[int]
    PHYSICAL_PORTS: Final[int]
    LEN: Final[int]
    MIN_LEN: Final[int]
    COE_SDO: Final[int]
    COE_SDO_INFO: Final[int]
    COE_PDO_ASSIGN: Final[int]
    COE_PDO_CONFIG: Final[int]
    COE_UPLOAD_AT_STARTUP: Final[int]
    COE_COMPLETE_ACCESS: Final[int]
    FLAG_ENABLE_SAFEOP: Final[int]
    FLAG_NOT_LRW: Final[int]
    PORT_NONE: Final[int]
    PORT_MII: Final[int]
    PORT_EBUS: Final[int]
    PORT_FAST_HOT_CONNECT: Final[int]

class sii_fmmu:
    """SII FMMU category: what each FMMU is for."""

    UNUSED: Final[int]
    OUTPUTS: Final[int]
    INPUTS: Final[int]
    MBOX_STATE: Final[int]
    PADDING: Final[int]

class sii_pdo:
    """SII TxPDO/RxPDO categories: PDO flags, record length."""

    FLAG_MANDATORY: Final[int]
    FLAG_DEFAULT: Final[int]
    FLAG_FIXED: Final[int]
    NO_SM: Final[int]
    RECORD_LEN: Final[int]

class mailbox:
    """Mailbox header length and types."""

    HEADER_LEN: Final[int]
    TYPE_ERR: Final[int]
    TYPE_AOE: Final[int]
    TYPE_EOE: Final[int]
    TYPE_COE: Final[int]
    TYPE_FOE: Final[int]
    TYPE_SOE: Final[int]
    TYPE_VOE: Final[int]
    MAX_COUNTER: Final[int]
    ERROR_REPLY_TYPE: Final[int]
    PROTOCOL_AOE: Final[int]
    PROTOCOL_EOE: Final[int]
    PROTOCOL_COE: Final[int]
    PROTOCOL_FOE: Final[int]
    PROTOCOL_SOE: Final[int]
    PROTOCOL_VOE: Final[int]

class mailbox_error:
    """Mailbox error codes."""

    ERR_SYNTAX: Final[int]
    ERR_UNSUPPORTED_PROTOCOL: Final[int]
    ERR_INVALID_CHANNEL: Final[int]
    ERR_SERVICE_NOT_SUPPORTED: Final[int]
    ERR_INVALID_HEADER: Final[int]
    ERR_SIZE_TOO_SHORT: Final[int]
    ERR_NO_MORE_MEMORY: Final[int]
    ERR_INVALID_SIZE: Final[int]

class coe:
    """CoE services, SDO specifiers, SDO information."""

    HEADER_LEN: Final[int]
    SEGMENT_HEADER_LEN: Final[int]
    MIN_SEGMENT_DATA: Final[int]
    SDO_HEADER_LEN: Final[int]
    SERVICE_EMERGENCY: Final[int]
    SERVICE_SDO_REQUEST: Final[int]
    SERVICE_SDO_RESPONSE: Final[int]
    SERVICE_TXPDO: Final[int]
    SERVICE_RXPDO: Final[int]
    SERVICE_SDO_INFORMATION: Final[int]
    CCS_DOWNLOAD_SEGMENT: Final[int]
    CCS_DOWNLOAD_INITIATE: Final[int]
    CCS_UPLOAD_INITIATE: Final[int]
    CCS_UPLOAD_SEGMENT: Final[int]
    CS_ABORT: Final[int]
    SCS_UPLOAD_SEGMENT: Final[int]
    SCS_DOWNLOAD_SEGMENT: Final[int]
    SCS_UPLOAD_INITIATE: Final[int]
    SCS_DOWNLOAD_INITIATE: Final[int]
    COMPLETE_ACCESS: Final[int]
    TOGGLE: Final[int]
    EXPEDITED: Final[int]
    SIZE_INDICATED: Final[int]
    LAST_SEGMENT: Final[int]
    EXPEDITED_UNUSED_SHIFT: Final[int]
    SEGMENT_UNUSED_SHIFT: Final[int]
    SPECIFIER_SHIFT: Final[int]
    INFO_OD_LIST_REQ: Final[int]
    INFO_OD_LIST_RESP: Final[int]
    INFO_OBJECT_DESC_REQ: Final[int]
    INFO_OBJECT_DESC_RESP: Final[int]
    INFO_ENTRY_DESC_REQ: Final[int]
    INFO_ENTRY_DESC_RESP: Final[int]
    INFO_ERROR: Final[int]
    INFO_INCOMPLETE: Final[int]
    INFO_OPCODE_MASK: Final[int]
    INFO_HEADER_LEN: Final[int]
    ACCESS_READ: Final[int]
    ACCESS_WRITE: Final[int]
    ACCESS_RXPDO: Final[int]
    ACCESS_TXPDO: Final[int]
    OD_LIST_ALL: Final[int]
    OBJECT_VAR: Final[int]
    OBJECT_ARRAY: Final[int]
    OBJECT_RECORD: Final[int]
    DEVICE_TYPE: Final[int]
    ERROR_REGISTER: Final[int]
    SOFTWARE_VERSION: Final[int]
    IDENTITY: Final[int]
    RXPDO_MAPPING: Final[int]
    RXPDO_MAPPING_LAST: Final[int]
    TXPDO_MAPPING: Final[int]
    TXPDO_MAPPING_LAST: Final[int]
    SM_COMM_TYPE: Final[int]
    SM_PDO_ASSIGN: Final[int]
    RXPDO_ASSIGN: Final[int]
    TXPDO_ASSIGN: Final[int]

class sdo_abort:
    """SDO abort codes."""

    ABORT_TOGGLE_BIT: Final[int]
    ABORT_TIMEOUT: Final[int]
    ABORT_INVALID_COMMAND: Final[int]
    ABORT_INVALID_BLOCK_SIZE: Final[int]
    ABORT_INVALID_SEQUENCE: Final[int]
    ABORT_CRC: Final[int]
    ABORT_OUT_OF_MEMORY: Final[int]
    ABORT_UNSUPPORTED_ACCESS: Final[int]
    ABORT_WRITE_ONLY: Final[int]
    ABORT_READ_ONLY: Final[int]
    ABORT_SUBINDEX0_NOT_ZERO: Final[int]
    ABORT_NO_COMPLETE_ACCESS: Final[int]
    ABORT_OBJECT_TOO_LONG: Final[int]
    ABORT_MAPPED_TO_RXPDO: Final[int]
    ABORT_NO_OBJECT: Final[int]
    ABORT_CANNOT_MAP: Final[int]
    ABORT_PDO_TOO_LONG: Final[int]
    ABORT_PARAMETER_INCOMPATIBLE: Final[int]
    ABORT_INTERNAL_INCOMPATIBLE: Final[int]
    ABORT_HARDWARE: Final[int]
    ABORT_LENGTH_MISMATCH: Final[int]
    ABORT_LENGTH_TOO_HIGH: Final[int]
    ABORT_LENGTH_TOO_LOW: Final[int]
    ABORT_NO_SUBINDEX: Final[int]
    ABORT_VALUE_RANGE: Final[int]
    ABORT_VALUE_TOO_HIGH: Final[int]
    ABORT_VALUE_TOO_LOW: Final[int]
    ABORT_MAX_BELOW_MIN: Final[int]
    ABORT_GENERAL: Final[int]
    ABORT_TRANSFER: Final[int]
    ABORT_LOCAL_CONTROL: Final[int]
    ABORT_DEVICE_STATE: Final[int]
    ABORT_NO_DICTIONARY: Final[int]
    ABORT_NO_DATA: Final[int]

class soe:
    """SoE header, opcodes, element flags, IDN and attribute fields."""

    HEADER_LEN: Final[int]
    OPCODE_READ_REQUEST: Final[int]
    OPCODE_READ_RESPONSE: Final[int]
    OPCODE_WRITE_REQUEST: Final[int]
    OPCODE_WRITE_RESPONSE: Final[int]
    OPCODE_NOTIFICATION: Final[int]
    OPCODE_SLAVE_INFO: Final[int]
    OPCODE_MASK: Final[int]
    INCOMPLETE: Final[int]
    ERROR: Final[int]
    DRIVE_SHIFT: Final[int]
    MAX_DRIVES: Final[int]
    ELEMENT_DATA_STATE: Final[int]
    ELEMENT_NAME: Final[int]
    ELEMENT_ATTRIBUTE: Final[int]
    ELEMENT_UNIT: Final[int]
    ELEMENT_MINIMUM: Final[int]
    ELEMENT_MAXIMUM: Final[int]
    ELEMENT_VALUE: Final[int]
    ELEMENT_DEFAULT: Final[int]
    IDN_PRODUCT: Final[int]
    IDN_SET_SHIFT: Final[int]
    IDN_NUMBER_MASK: Final[int]
    IDN_AT_LIST: Final[int]
    IDN_MDT_LIST: Final[int]
    IDN_CONTROL_WORD: Final[int]
    IDN_STATUS_WORD: Final[int]
    LIST_HEADER_LEN: Final[int]
    ATTR_FACTOR_MASK: Final[int]
    ATTR_LEN_SHIFT: Final[int]
    ATTR_LEN_1: Final[int]
    ATTR_LEN_2: Final[int]
    ATTR_LEN_4: Final[int]
    ATTR_LEN_8: Final[int]
    ATTR_LIST: Final[int]
    ATTR_COMMAND: Final[int]
    ATTR_TYPE_SHIFT: Final[int]
    ATTR_TYPE_BINARY: Final[int]
    ATTR_TYPE_UNSIGNED: Final[int]
    ATTR_TYPE_SIGNED: Final[int]
    ATTR_TYPE_HEX: Final[int]
    ATTR_TYPE_TEXT: Final[int]
    ATTR_TYPE_IDN: Final[int]
    ATTR_TYPE_FLOAT: Final[int]
    ATTR_DECIMALS_SHIFT: Final[int]
    ATTR_WP_PREOP: Final[int]
    ATTR_WP_SAFEOP: Final[int]
    ATTR_WP_OP: Final[int]

class soe_error:
    """SoE error codes."""

    ERR_NONE: Final[int]
    ERR_NO_IDN: Final[int]
    ERR_INVALID_ACCESS_ELEMENT1: Final[int]
    ERR_NO_NAME: Final[int]
    ERR_NAME_TOO_SHORT: Final[int]
    ERR_NAME_TOO_LONG: Final[int]
    ERR_NAME_READ_ONLY: Final[int]
    ERR_NAME_WRITE_PROTECTED: Final[int]
    ERR_ATTRIBUTE_TOO_SHORT: Final[int]
    ERR_ATTRIBUTE_TOO_LONG: Final[int]
    ERR_ATTRIBUTE_READ_ONLY: Final[int]
    ERR_ATTRIBUTE_WRITE_PROTECTED: Final[int]
    ERR_NO_UNIT: Final[int]
    ERR_UNIT_TOO_SHORT: Final[int]
    ERR_UNIT_TOO_LONG: Final[int]
    ERR_UNIT_READ_ONLY: Final[int]
    ERR_UNIT_WRITE_PROTECTED: Final[int]
    ERR_NO_MINIMUM: Final[int]
    ERR_MINIMUM_TOO_SHORT: Final[int]
    ERR_MINIMUM_TOO_LONG: Final[int]
    ERR_MINIMUM_READ_ONLY: Final[int]
    ERR_MINIMUM_WRITE_PROTECTED: Final[int]
    ERR_NO_MAXIMUM: Final[int]
    ERR_MAXIMUM_TOO_SHORT: Final[int]
    ERR_MAXIMUM_TOO_LONG: Final[int]
    ERR_MAXIMUM_READ_ONLY: Final[int]
    ERR_MAXIMUM_WRITE_PROTECTED: Final[int]
    ERR_DATA_TOO_SHORT: Final[int]
    ERR_DATA_TOO_LONG: Final[int]
    ERR_DATA_READ_ONLY: Final[int]
    ERR_DATA_WRITE_PROTECTED: Final[int]
    ERR_DATA_BELOW_MINIMUM: Final[int]
    ERR_DATA_ABOVE_MAXIMUM: Final[int]
    ERR_DATA_INVALID: Final[int]
    ERR_DATA_PASSWORD: Final[int]
    ERR_DATA_CYCLIC: Final[int]
    ERR_DATA_INDIRECT: Final[int]
    ERR_DATA_OTHER_SETTINGS: Final[int]
    ERR_COMMAND_ACTIVE: Final[int]
    ERR_COMMAND_NOT_INTERRUPTIBLE: Final[int]
    ERR_COMMAND_NOT_NOW: Final[int]
    ERR_COMMAND_INVALID: Final[int]
    ERR_NO_DATA_STATE: Final[int]
    ERR_NO_DEFAULT: Final[int]
    ERR_DEFAULT_TOO_LONG: Final[int]
    ERR_DEFAULT_READ_ONLY: Final[int]
    ERR_INVALID_DRIVE: Final[int]
    ERR_GENERAL: Final[int]
    ERR_NO_ELEMENT: Final[int]

class foe:
    """FoE header length and opcodes."""

    HEADER_LEN: Final[int]
    OVERHEAD: Final[int]
    OPCODE_READ: Final[int]
    OPCODE_WRITE: Final[int]
    OPCODE_DATA: Final[int]
    OPCODE_ACK: Final[int]
    OPCODE_ERROR: Final[int]
    OPCODE_BUSY: Final[int]

class foe_error:
    """FoE error codes."""

    ERR_NOT_DEFINED: Final[int]
    ERR_NOT_FOUND: Final[int]
    ERR_ACCESS_DENIED: Final[int]
    ERR_DISK_FULL: Final[int]
    ERR_ILLEGAL: Final[int]
    ERR_PACKET_NUMBER: Final[int]
    ERR_ALREADY_EXISTS: Final[int]
    ERR_NO_USER: Final[int]
    ERR_BOOTSTRAP_ONLY: Final[int]
    ERR_NOT_BOOTSTRAP: Final[int]
    ERR_NO_RIGHTS: Final[int]
    ERR_PROGRAM: Final[int]
    ERR_CHECKSUM: Final[int]
    ERR_INVALID_FIRMWARE: Final[int]
    ERR_NO_FILE: Final[int]

class dtype:
    """CoE data type codes."""

    BOOL: Final[int]
    INT8: Final[int]
    INT16: Final[int]
    INT32: Final[int]
    UINT8: Final[int]
    UINT16: Final[int]
    UINT32: Final[int]
    REAL32: Final[int]
    VISIBLE_STRING: Final[int]
    OCTET_STRING: Final[int]
    UNICODE_STRING: Final[int]
    INT24: Final[int]
    REAL64: Final[int]
    INT64: Final[int]
    UINT24: Final[int]
    UINT64: Final[int]
    BITARR8: Final[int]
    BITARR16: Final[int]
    BITARR32: Final[int]
    BIT1: Final[int]
    BIT8: Final[int]

class cw:
    """CiA 402 controlword bits."""

    SWITCH_ON: Final[int]
    ENABLE_VOLTAGE: Final[int]
    QUICK_STOP: Final[int]
    ENABLE_OPERATION: Final[int]
    NEW_SETPOINT: Final[int]
    CHANGE_SET_IMMEDIATELY: Final[int]
    RELATIVE: Final[int]
    FAULT_RESET: Final[int]
    HALT: Final[int]

class sw:
    """CiA 402 statusword bits."""

    READY_TO_SWITCH_ON: Final[int]
    SWITCHED_ON: Final[int]
    OPERATION_ENABLED: Final[int]
    FAULT: Final[int]
    VOLTAGE_ENABLED: Final[int]
    QUICK_STOP: Final[int]
    SWITCH_ON_DISABLED: Final[int]
    WARNING: Final[int]
    REMOTE: Final[int]
    TARGET_REACHED: Final[int]
    INTERNAL_LIMIT: Final[int]
    MODE_12: Final[int]
    MODE_13: Final[int]
    STATE_MASK: Final[int]
    STATE_MASK_QUICK_STOP: Final[int]

class cia402:
    """CiA 402 commands, objects and mode codes."""

    SHUTDOWN: Final[int]
    SWITCH_ON: Final[int]
    ENABLE_OPERATION: Final[int]
    DISABLE_VOLTAGE: Final[int]
    QUICK_STOP: Final[int]
    FAULT_RESET: Final[int]
    AXIS_OFFSET: Final[int]
    MAX_AXES: Final[int]
    ERROR_CODE: Final[int]
    CONTROLWORD: Final[int]
    STATUSWORD: Final[int]
    QUICK_STOP_OPTION: Final[int]
    MODES_OF_OPERATION: Final[int]
    MODES_OF_OPERATION_DISPLAY: Final[int]
    POSITION_ACTUAL: Final[int]
    FOLLOWING_ERROR_WINDOW: Final[int]
    FOLLOWING_ERROR_TIMEOUT: Final[int]
    POSITION_WINDOW: Final[int]
    VELOCITY_WINDOW: Final[int]
    MAX_TORQUE: Final[int]
    MOTOR_RATED_TORQUE: Final[int]
    HOME_OFFSET: Final[int]
    MAX_MOTOR_SPEED: Final[int]
    QUICK_STOP_DECELERATION: Final[int]
    POSITION_ENCODER_RESOLUTION: Final[int]
    GEAR_RATIO: Final[int]
    HOMING_SPEEDS: Final[int]
    HOMING_ACCELERATION: Final[int]
    VELOCITY_OFFSET: Final[int]
    TORQUE_OFFSET: Final[int]
    TOUCH_PROBE_FUNCTION: Final[int]
    TOUCH_PROBE_STATUS: Final[int]
    TOUCH_PROBE_1_POSITIVE: Final[int]
    TOUCH_PROBE_1_NEGATIVE: Final[int]
    SUPPORTED_HOMING_METHODS: Final[int]
    DIGITAL_INPUTS: Final[int]
    DIGITAL_OUTPUTS: Final[int]
    VELOCITY_ACTUAL: Final[int]
    TARGET_TORQUE: Final[int]
    TORQUE_ACTUAL: Final[int]
    TARGET_POSITION: Final[int]
    SOFTWARE_POSITION_LIMIT: Final[int]
    PROFILE_VELOCITY: Final[int]
    PROFILE_ACCELERATION: Final[int]
    PROFILE_DECELERATION: Final[int]
    HOMING_METHOD: Final[int]
    INTERPOLATION_TIME_PERIOD: Final[int]
    FOLLOWING_ERROR_ACTUAL: Final[int]
    TARGET_VELOCITY: Final[int]
    SUPPORTED_MODES: Final[int]

class mode:
    """CiA 402 modes of operation (0x6060 values)."""

    NONE: Final[int]
    PP: Final[int]
    VL: Final[int]
    PV: Final[int]
    TQ: Final[int]
    HM: Final[int]
    IP: Final[int]
    CSP: Final[int]
    CSV: Final[int]
    CST: Final[int]
