//! Run-time choice of instruction set for the vector kernels.
//!
//! The kernels are plain Rust loops that the compiler vectorises. The x86-64 baseline only guarantees SSE2
//! (8 × i16 per instruction); most machines, the consoles' x86 boards included, have AVX2 (16 × i16). So on
//! x86-64 each kernel is compiled twice from the same source, for the baseline and with AVX2, and the AVX2 copy
//! runs when the CPU has it. Other targets (aarch64: NEON is its baseline) compile the source once. The two x86
//! copies are compared bit for bit in `tests` below and in tests/orb.rs.

/// Defines `$name`, which runs `$portable` compiled with AVX2 when the CPU has it, else `$portable` as is.
/// `$portable` is a private `#[inline(always)]` function with the given body (and public in the crate so
/// that parity tests can call the baseline copy).
macro_rules! multiversion {
    ($(#[$meta:meta])* fn $name:ident / $portable:ident ($($arg:ident : $ty:ty),* $(,)?) $(-> $ret:ty)? $body:block) => {
        $(#[$meta])*
        #[inline(always)]
        pub(crate) fn $portable($($arg: $ty),*) $(-> $ret)? $body

        $(#[$meta])*
        #[inline(never)] // a stage of its own in profiles
        pub(crate) fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2")]
                fn avx2($($arg: $ty),*) $(-> $ret)? {
                    $portable($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU has AVX2 (checked on the line above), the only requirement of `avx2`,
                    // which is `$portable` compiled with that feature enabled.
                    return unsafe { avx2($($arg),*) };
                }
            }
            $portable($($arg),*)
        }
    };
}

pub(crate) use multiversion;
