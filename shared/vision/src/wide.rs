//! The renderer's loops are compiled twice: for the target's baseline and, on x86-64, for AVX2, whose
//! vector instructions take twice the pixels of the baseline's SSE2 (and round without a library
//! call). The AVX2 build runs when the CPU has it, checked at run time, so one binary still runs on
//! any x86-64. Both builds give the same bits: the loops are integer arithmetic and IEEE operations
//! that the compiler never contracts into fused ones (tested). Perception gained nothing from it
//! (its time goes to branches and scattered votes, not to wide arithmetic) and has one build.

/// Whether this CPU runs the AVX2 build of the loops (never off x86-64).
#[inline]
pub(crate) fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
