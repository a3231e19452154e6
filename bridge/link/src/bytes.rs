//! The wire types as bytes: what may be read and written as it is ([`Pod`]), and the two
//! conversions every sender and receiver of the link uses.

use deltaloop_transport::wire::{ControlMsg, RefSample, StateMsg, TelemetryMsg, TorqueMsg};

/// Plain old data: every bit pattern is a valid value and there is no implicit padding, so its
/// bytes may be read and written as they are.
///
/// # Safety
/// Only for `#[repr(C)]` types of integer and float fields (and arrays of them) whose explicit
/// `_pad` fields leave no implicit padding.
pub unsafe trait Pod: Copy + 'static {}
// SAFETY: repr(C), u64/u32/f64 fields and arrays, explicit padding (docs/protocol.md §4).
unsafe impl Pod for StateMsg {}
// SAFETY: as above.
unsafe impl Pod for TorqueMsg {}
// SAFETY: as above.
unsafe impl Pod for ControlMsg {}
// SAFETY: as above.
unsafe impl Pod for RefSample {}
// SAFETY: as above.
unsafe impl Pod for TelemetryMsg {}
// SAFETY: a primitive.
unsafe impl Pod for u64 {}
// SAFETY: a primitive.
unsafe impl Pod for u32 {}

/// The bytes of `v`.
pub fn bytes_of<T: Pod>(v: &T) -> &[u8] {
    // SAFETY: T is Pod: all of its size_of bytes are initialised.
    unsafe { std::slice::from_raw_parts((v as *const T).cast::<u8>(), size_of::<T>()) }
}

/// The bytes of a slice of `T`.
pub fn bytes_of_slice<T: Pod>(v: &[T]) -> &[u8] {
    // SAFETY: as in bytes_of, for every element; the length is the slice's in bytes.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast::<u8>(), std::mem::size_of_val(v)) }
}

/// A `T` read from exactly its bytes (None if `b` has another length).
pub fn read<T: Pod>(b: &[u8]) -> Option<T> {
    (b.len() == size_of::<T>()).then(|| {
        // SAFETY: T is Pod (any bit pattern is valid) and b holds size_of::<T>() bytes.
        unsafe { std::ptr::read_unaligned(b.as_ptr().cast::<T>()) }
    })
}
