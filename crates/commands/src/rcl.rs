//! The few rcl functions the command path calls, looked up at run time in the librcl and
//! librcutils that rclpy has already loaded into the process.
//!
//! Linking against rcl at build time would tie the extension to one ROS installation and make
//! every build need ROS; instead Python passes the paths of the loaded libraries (from
//! /proc/self/maps) and the addresses of the rcl objects rclpy created (`handle.pointer`), and
//! this module declares the structures it touches exactly as rcl/wait.h, rcutils/allocator.h,
//! rcutils/types/uint8_array.h and rmw/types.h (ROS 2 Jazzy) lay them out.

use std::ffi::{c_char, c_void, CStr, CString};
use std::ptr;

pub type RclRet = i32;
pub const RCL_RET_OK: RclRet = 0;
pub const RCL_RET_TIMEOUT: RclRet = 2;
pub const RCL_RET_SUBSCRIPTION_TAKE_FAILED: RclRet = 401;

/// rcutils_allocator_t
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Allocator {
    allocate: *mut c_void,
    deallocate: *mut c_void,
    reallocate: *mut c_void,
    zero_allocate: *mut c_void,
    state: *mut c_void,
}

/// rcutils_uint8_array_t (rcl_serialized_message_t)
#[repr(C)]
pub struct SerializedMessage {
    pub buffer: *mut u8,
    pub buffer_length: usize,
    pub buffer_capacity: usize,
    pub allocator: Allocator,
}

/// rcl_wait_set_t: six (array, size) pairs and the implementation pointer.
#[repr(C)]
pub struct WaitSet {
    subscriptions: *mut *const c_void,
    size_of_subscriptions: usize,
    guard_conditions: *mut *const c_void,
    size_of_guard_conditions: usize,
    timers: *mut *const c_void,
    size_of_timers: usize,
    clients: *mut *const c_void,
    size_of_clients: usize,
    services: *mut *const c_void,
    size_of_services: usize,
    events: *mut *const c_void,
    size_of_events: usize,
    implementation: *mut c_void,
}

/// rmw_gid_t (Jazzy: `RMW_GID_STORAGE_SIZE` = 16).
#[repr(C)]
#[derive(Clone, Copy)]
pub struct Gid {
    implementation_identifier: *const c_char,
    pub data: [u8; 16],
}

/// rmw_message_info_t as rmw/types.h (Jazzy) lays it out: the source and received timestamps
/// (int64 ns, system clock), the publication and reception sequence numbers, the publisher's
/// GID (which DataWriter sent the message: the command path's fairness and the control lease
/// go by it) and the intra-process flag; generous room follows in case an rmw writes more.
#[repr(C, align(8))]
pub struct MessageInfo {
    pub source_timestamp: i64,
    pub received_timestamp: i64,
    pub publication_sequence_number: u64,
    pub reception_sequence_number: u64,
    pub publisher_gid: Gid,
    pub from_intra_process: bool,
    _room: [u8; 184],
}

impl Default for MessageInfo {
    fn default() -> Self {
        MessageInfo {
            source_timestamp: 0,
            received_timestamp: 0,
            publication_sequence_number: 0,
            reception_sequence_number: 0,
            publisher_gid: Gid {
                implementation_identifier: ptr::null(),
                data: [0; 16],
            },
            from_intra_process: false,
            _room: [0; 184],
        }
    }
}

type WaitSetInit = unsafe extern "C" fn(
    *mut WaitSet,
    usize,
    usize,
    usize,
    usize,
    usize,
    usize,
    *mut c_void,
    Allocator,
) -> RclRet;
type WaitSetFini = unsafe extern "C" fn(*mut WaitSet) -> RclRet;
type WaitSetClear = unsafe extern "C" fn(*mut WaitSet) -> RclRet;
type WaitSetAddSubscription =
    unsafe extern "C" fn(*mut WaitSet, *const c_void, *mut usize) -> RclRet;
type Wait = unsafe extern "C" fn(*mut WaitSet, i64) -> RclRet;
type TakeSerialized = unsafe extern "C" fn(
    *const c_void,
    *mut SerializedMessage,
    *mut MessageInfo,
    *mut c_void,
) -> RclRet;
type PublishSerialized =
    unsafe extern "C" fn(*const c_void, *const SerializedMessage, *mut c_void) -> RclRet;
type SendRequest = unsafe extern "C" fn(*const c_void, *const c_void, *mut i64) -> RclRet;
type ServerIsAvailable = unsafe extern "C" fn(*const c_void, *const c_void, *mut bool) -> RclRet;
type ResetError = unsafe extern "C" fn();
/// rcutils_error_string_t: the formatted error, returned by value.
#[repr(C)]
pub struct ErrorString {
    text: [c_char; 1024],
}
type GetError = unsafe extern "C" fn() -> ErrorString;
type DefaultAllocator = unsafe extern "C" fn() -> Allocator;
type ArrayInit = unsafe extern "C" fn(*mut SerializedMessage, usize, *const Allocator) -> i32;
type ArrayFini = unsafe extern "C" fn(*mut SerializedMessage) -> i32;

/// The rcl entry points, resolved once.
pub struct Rcl {
    wait_set_init: WaitSetInit,
    wait_set_fini: WaitSetFini,
    wait_set_clear: WaitSetClear,
    wait_set_add_subscription: WaitSetAddSubscription,
    wait: Wait,
    take_serialized: TakeSerialized,
    publish_serialized: PublishSerialized,
    send_request: SendRequest,
    server_is_available: ServerIsAvailable,
    reset_error: ResetError,
    get_error: GetError,
    default_allocator: DefaultAllocator,
    array_init: ArrayInit,
    array_fini: ArrayFini,
}

// SAFETY: plain function pointers into shared libraries that stay loaded for the process's life
// (they were loaded by rclpy and are opened again here, which only raises their reference count).
unsafe impl Send for Rcl {}
unsafe impl Sync for Rcl {}

fn open(path: &str) -> Result<*mut c_void, String> {
    let c = CString::new(path).map_err(|_| format!("library path {path:?} contains NUL"))?;
    // SAFETY: dlopen with a valid C string; RTLD_NOLOAD only returns a library already loaded.
    let handle = unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_NOW | libc::RTLD_NOLOAD) };
    if handle.is_null() {
        return Err(format!(
            "{path} is not loaded in this process (import rclpy first)"
        ));
    }
    Ok(handle)
}

fn symbol<T: Copy>(library: *mut c_void, path: &str, name: &str) -> Result<T, String> {
    assert_eq!(std::mem::size_of::<T>(), std::mem::size_of::<*mut c_void>());
    let c = CString::new(name).expect("symbol names have no NUL");
    // SAFETY: dlsym on a handle from dlopen; the pointer is converted to the matching function
    // pointer type, which the declarations above take from the rcl/rcutils headers.
    unsafe {
        let p = libc::dlsym(library, c.as_ptr());
        if p.is_null() {
            return Err(format!("{path} has no symbol {name}"));
        }
        Ok(std::mem::transmute_copy::<*mut c_void, T>(&p))
    }
}

impl Rcl {
    /// Resolve the entry points in the already loaded `librcl` and `librcutils`.
    pub fn load(librcl: &str, librcutils: &str) -> Result<Rcl, String> {
        let rcl = open(librcl)?;
        let rcutils = open(librcutils)?;
        Ok(Rcl {
            wait_set_init: symbol(rcl, librcl, "rcl_wait_set_init")?,
            wait_set_fini: symbol(rcl, librcl, "rcl_wait_set_fini")?,
            wait_set_clear: symbol(rcl, librcl, "rcl_wait_set_clear")?,
            wait_set_add_subscription: symbol(rcl, librcl, "rcl_wait_set_add_subscription")?,
            wait: symbol(rcl, librcl, "rcl_wait")?,
            take_serialized: symbol(rcl, librcl, "rcl_take_serialized_message")?,
            publish_serialized: symbol(rcl, librcl, "rcl_publish_serialized_message")?,
            send_request: symbol(rcl, librcl, "rcl_send_request")?,
            server_is_available: symbol(rcl, librcl, "rcl_service_server_is_available")?,
            reset_error: symbol(rcutils, librcutils, "rcutils_reset_error")?,
            get_error: symbol(rcutils, librcutils, "rcutils_get_error_string")?,
            default_allocator: symbol(rcutils, librcutils, "rcutils_get_default_allocator")?,
            array_init: symbol(rcutils, librcutils, "rcutils_uint8_array_init")?,
            array_fini: symbol(rcutils, librcutils, "rcutils_uint8_array_fini")?,
        })
    }

    /// The last rcl error as text, and clear it (rcl keeps one error per thread).
    pub fn take_error(&self, ret: RclRet) -> String {
        // SAFETY: get_error copies rcl's thread-local message into a NUL-terminated array
        // (rcutils guarantees the terminator); reset_error clears that state.
        let text = unsafe {
            let e = (self.get_error)();
            CStr::from_ptr(e.text.as_ptr())
                .to_string_lossy()
                .into_owned()
        };
        // SAFETY: see above.
        unsafe { (self.reset_error)() };
        if text.is_empty() {
            format!("rcl error {ret}")
        } else {
            format!("rcl error {ret}: {text}")
        }
    }
}

/// A wait set on one subscription, owned by the thread that waits.
pub struct SubscriptionWaiter<'r> {
    rcl: &'r Rcl,
    wait_set: WaitSet,
    subscription: *const c_void,
    message: SerializedMessage,
    info: MessageInfo,
}

impl<'r> SubscriptionWaiter<'r> {
    /// # Safety
    /// `context` and `subscription` must be a valid `rcl_context_t*` and `rcl_subscription_t*`
    /// that outlive the waiter.
    pub unsafe fn new(
        rcl: &'r Rcl,
        context: *mut c_void,
        subscription: *const c_void,
        capacity: usize,
    ) -> Result<Self, String> {
        let allocator = (rcl.default_allocator)();
        let mut wait_set: WaitSet = std::mem::zeroed();
        let ret = (rcl.wait_set_init)(&mut wait_set, 1, 0, 0, 0, 0, 0, context, allocator);
        if ret != RCL_RET_OK {
            return Err(format!("creating the wait set: {}", rcl.take_error(ret)));
        }
        let mut message = SerializedMessage {
            buffer: ptr::null_mut(),
            buffer_length: 0,
            buffer_capacity: 0,
            allocator,
        };
        let ret = (rcl.array_init)(&mut message, capacity, &allocator);
        if ret != RCL_RET_OK {
            (rcl.wait_set_fini)(&mut wait_set);
            return Err(format!(
                "allocating the message buffer: {}",
                rcl.take_error(ret)
            ));
        }
        Ok(SubscriptionWaiter {
            rcl,
            wait_set,
            subscription,
            message,
            info: MessageInfo::default(),
        })
    }

    /// Wait up to `timeout_ns` for the subscription to have data. Ok(false) on timeout.
    pub fn wait(&mut self, timeout_ns: i64) -> Result<bool, String> {
        // SAFETY: the wait set was initialised in new() and the subscription outlives self.
        unsafe {
            let ret = (self.rcl.wait_set_clear)(&mut self.wait_set);
            if ret != RCL_RET_OK {
                return Err(self.rcl.take_error(ret));
            }
            let ret = (self.rcl.wait_set_add_subscription)(
                &mut self.wait_set,
                self.subscription,
                ptr::null_mut(),
            );
            if ret != RCL_RET_OK {
                return Err(self.rcl.take_error(ret));
            }
            match (self.rcl.wait)(&mut self.wait_set, timeout_ns) {
                RCL_RET_OK => Ok(true),
                RCL_RET_TIMEOUT => Ok(false),
                ret => Err(self.rcl.take_error(ret)),
            }
        }
    }

    /// Take one serialized message: Ok(None) when there is none left.
    pub fn take(&mut self) -> Result<Option<(&[u8], &MessageInfo)>, String> {
        // SAFETY: the buffer was initialised by rcutils_uint8_array_init; rcl grows it with its
        // allocator when a message is larger.
        unsafe {
            match (self.rcl.take_serialized)(
                self.subscription,
                &mut self.message,
                &mut self.info,
                ptr::null_mut(),
            ) {
                RCL_RET_OK => Ok(Some((
                    std::slice::from_raw_parts(self.message.buffer, self.message.buffer_length),
                    &self.info,
                ))),
                RCL_RET_SUBSCRIPTION_TAKE_FAILED => Ok(None),
                ret => Err(self.rcl.take_error(ret)),
            }
        }
    }
}

impl Drop for SubscriptionWaiter<'_> {
    fn drop(&mut self) {
        // SAFETY: both were initialised in new() and are finalised once.
        unsafe {
            (self.rcl.array_fini)(&mut self.message);
            (self.rcl.wait_set_fini)(&mut self.wait_set);
        }
    }
}

/// Publish already serialized bytes on an rcl publisher.
///
/// # Safety
/// `publisher` must be a valid `rcl_publisher_t*` for the message type `data` holds.
pub unsafe fn publish_serialized(
    rcl: &Rcl,
    publisher: *const c_void,
    data: &mut [u8],
) -> Result<(), String> {
    let message = SerializedMessage {
        buffer: data.as_mut_ptr(),
        buffer_length: data.len(),
        buffer_capacity: data.len(),
        allocator: (rcl.default_allocator)(),
    };
    match (rcl.publish_serialized)(publisher, &message, ptr::null_mut()) {
        RCL_RET_OK => Ok(()),
        ret => Err(rcl.take_error(ret)),
    }
}

/// Send a request on an rcl client: its sequence number.
///
/// # Safety
/// `client` must be a valid `rcl_client_t*` and `request` point to the C message struct of
/// its service's request type.
pub unsafe fn send_request(
    rcl: &Rcl,
    client: *const c_void,
    request: *const c_void,
) -> Result<i64, String> {
    let mut sequence = 0i64;
    match (rcl.send_request)(client, request, &mut sequence) {
        RCL_RET_OK => Ok(sequence),
        ret => Err(rcl.take_error(ret)),
    }
}

/// Whether a server for `client`'s service is known to `node`'s graph.
///
/// # Safety
/// `node` and `client` must be a valid `rcl_node_t*` and an `rcl_client_t*` of that node.
pub unsafe fn server_is_available(
    rcl: &Rcl,
    node: *const c_void,
    client: *const c_void,
) -> Result<bool, String> {
    let mut available = false;
    match (rcl.server_is_available)(node, client, &mut available) {
        RCL_RET_OK => Ok(available),
        ret => Err(rcl.take_error(ret)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn message_info_has_the_rmw_layout() {
        // rmw/types.h (Jazzy): two int64 stamps, two uint64 sequence numbers, then rmw_gid_t
        // (a pointer and 16 bytes), then the bool.
        assert_eq!(
            std::mem::offset_of!(MessageInfo, publication_sequence_number),
            16
        );
        assert_eq!(std::mem::offset_of!(MessageInfo, publisher_gid), 32);
        assert_eq!(
            std::mem::offset_of!(MessageInfo, publisher_gid) + std::mem::offset_of!(Gid, data),
            40
        );
        assert_eq!(std::mem::offset_of!(MessageInfo, from_intra_process), 56);
    }
}
