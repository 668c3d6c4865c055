//! Inner loops compiled twice: for the baseline target (the scalar
//! fallback, which the compiler still vectorises with SSE2) and for AVX2 +
//! POPCNT, chosen at run time by [`Isa::detect`]. The loops are plain safe
//! Rust over slices; only the call into the AVX2 build is `unsafe`, and only
//! after the CPU has reported the features it needs. No multiply and add are
//! fused (Rust never contracts them), so both builds give the same bits.
//!
//! Used by the dense matchers (`stereo`), the MRI filters and the
//! phantom's renderer; imports nothing of the crate.

/// The instruction set the kernels run with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// Baseline x86-64 / any other architecture.
    Scalar,
    /// x86-64 with AVX2 and POPCNT.
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Isa {
    /// The best instruction set this CPU supports.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("popcnt")
        {
            return Isa::Avx2;
        }
        Isa::Scalar
    }
}

/// Defines each kernel once as an always-inlined body, a copy compiled with
/// AVX2 + POPCNT enabled, and an `Isa` method that picks one. Usable from any
/// module (`use crate::simd::kernels;`); the method's argument types
/// must be visible where it is invoked.
macro_rules! kernels {
    ($(
        $(#[$doc:meta])*
        fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block
    )*) => {
        impl $crate::simd::Isa {
            $(
                $(#[$doc])*
                #[inline]
                #[allow(clippy::too_many_arguments)]
                pub(crate) fn $name(self, $($arg: $ty),*) $(-> $ret)? {
                    #[inline(always)]
                    #[allow(clippy::too_many_arguments)]
                    fn generic($($arg: $ty),*) $(-> $ret)? $body

                    #[cfg(target_arch = "x86_64")]
                    #[target_feature(enable = "avx2,popcnt")]
                    #[allow(clippy::too_many_arguments)]
                    fn avx2($($arg: $ty),*) $(-> $ret)? { generic($($arg),*) }

                    match self {
                        #[cfg(target_arch = "x86_64")]
                        // SAFETY: `Isa::Avx2` is only made by `Isa::detect` after the
                        // CPU reported AVX2 and POPCNT, the only features `avx2`
                        // is compiled with beyond the baseline; the body is safe code.
                        $crate::simd::Isa::Avx2 => unsafe { avx2($($arg),*) },
                        $crate::simd::Isa::Scalar => generic($($arg),*),
                    }
                }
            )*
        }
    };
}
pub(crate) use kernels;

kernels! {
    /// out += w v, element by element (the convolutions' inner loop, in the
    /// MRI filters and the phantom's blur: AVX2 works eight lanes at a time
    /// where SSE2 works four, with the same bits, as no multiply and add
    /// are fused).
    fn add_scaled(out: &mut [f32], w: f32, v: &[f32]) {
        for (o, v) in out.iter_mut().zip(v) {
            *o += w * v;
        }
    }
}
