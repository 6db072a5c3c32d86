//! Kernels' inner loops compiled more than once: for the vector instructions of newer CPUs
//! (AVX-512, AVX2), picked at run time, and for any x86-64 CPU (the baseline, SSE2).
//! [`dispatched`] writes the public function and its copies from the portable body.

/// Defines the public function `$name` that runs `$portable` (an `#[inline(always)]` function
/// of the same arguments) compiled with the first of the x86-64 target features `$feature`
/// (string literals, tried in order) that the CPU has (checked at run time), else the
/// baseline build of it. Each copy inlines `$portable`'s body, so the compiler vectorises it
/// for that feature; results are the same in every copy.
///
/// ```ignore
/// dispatched! {
///     /// Docs of the public function.
///     pub fn encode(points: &[f32], out: &mut [f32]) = encode_portable for ["avx512f", "avx2"];
/// }
/// ```
#[macro_export]
macro_rules! dispatched {
    (
        $(#[$attr:meta])*
        $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?
            = $portable:ident for [$($feature:tt),+ $(,)?];
    ) => {
        $(#[$attr])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            $crate::dispatched!(
                @try [$($feature),+] $portable($($arg: $ty),*) $(-> $ret)?
            );
            $portable($($arg),*)
        }
    };
    // The copy for the first feature, run when the CPU has it; then the next feature's.
    (@try [$feature:tt $(, $rest:tt)*] $portable:ident($($arg:ident: $ty:ty),*) $(-> $ret:ty)?) => {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = $feature)]
            unsafe fn compiled($($arg: $ty),*) $(-> $ret)? {
                $portable($($arg),*)
            }
            if std::arch::is_x86_feature_detected!($feature) {
                // SAFETY: the CPU has the feature, checked just above.
                return unsafe { compiled($($arg),*) };
            }
        }
        $crate::dispatched!(
            @try [$($rest),*] $portable($($arg: $ty),*) $(-> $ret)?
        );
    };
    (@try [] $($_:tt)*) => {};
}

pub use crate::dispatched;
