//! The per-sample loops compiled twice: as built (SSE2 on x86-64, the portable baseline) and,
//! chosen at run time, for AVX2 and FMA, whose eight-lane registers take the lane loops of
//! the tracker and the full-spectrum sums in half as many steps. The order search's
//! candidates and the sample fit's sites and dictionary columns are vectorised the same way.
//!
//! Rust never fuses a multiply and an add on its own, so both builds do the same operations
//! in the same order and give the same results bit for bit (tested on whole sweeps); only
//! their speed differs (`filmscope bench` prints both).

/// Runs `f`, compiled for AVX2 and FMA when `wide` and the CPU has them (detected at run
/// time; x86-64 with `std` only), else as built. `f` and what it calls must be inlined into
/// it (`#[inline(always)]`) to be compiled for the wider instructions.
#[inline(always)]
pub fn wide<R>(wide: bool, f: impl FnOnce() -> R) -> R {
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    if wide && has_avx2_fma() {
        #[target_feature(enable = "avx2,fma")]
        fn avx2_fma<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
        // SAFETY: `avx2_fma` needs AVX2 and FMA, which the CPU was found to have.
        #[allow(unsafe_code)]
        return unsafe { avx2_fma(f) };
    }
    let _ = wide;
    f()
}

/// Whether [`wide`] runs its work for AVX2 and FMA on this CPU when asked to.
pub fn has_avx2_fma() -> bool {
    #[cfg(all(feature = "std", target_arch = "x86_64"))]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(all(feature = "std", target_arch = "x86_64")))]
    {
        false
    }
}
