//! A cache hint for loops whose loads the hardware cannot predict: the runs of a sweep that do not
//! continue the run before them, the PDFs of surface links.

/// Asks the cache for the line holding `p` (a hint: never faults, whatever the address; nothing on
/// targets without one).
#[inline(always)]
pub fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch has no architectural effect and never faults.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p as *const i8)
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}
