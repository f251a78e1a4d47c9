//! Which SIMD build of the hot loops runs, chosen at run time: a wall's render nodes differ
//! (AVX2 on some, AVX-512 on others), and one binary serves them all. Every build runs the
//! same operations in the same order, and Rust never contracts a multiply and an add into an
//! FMA on its own, so all give bit-identical pixels; the tests check each against the portable
//! one on every machine they run on.
//!
//! Every entry point with SIMD builds is declared once with `isa_builds!`, which writes its
//! builds and the dispatch to them (as Embree's `DEFINE_INTERSECTOR1` does), so the choice is
//! made the same way everywhere: [`Isa::runnable_within`].

/// A build of the hot loops, narrowest first (so `<` compares widths).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// The baseline (SSE2 on x86-64): runs anywhere.
    Portable,
    /// 8-wide lanes.
    Avx2,
    /// 16-wide lanes (AVX-512 F, with VL, BW and DQ for the narrower operations).
    Avx512,
}

impl Isa {
    /// Whether this CPU can run the build.
    pub fn is_available(self) -> bool {
        match self {
            Isa::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => {
                std::arch::is_x86_feature_detected!("avx512f")
                    && std::arch::is_x86_feature_detected!("avx512vl")
                    && std::arch::is_x86_feature_detected!("avx512bw")
                    && std::arch::is_x86_feature_detected!("avx512dq")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// Every build this CPU can run, widest last.
    pub fn available() -> Vec<Isa> {
        [Isa::Portable, Isa::Avx2, Isa::Avx512]
            .into_iter()
            .filter(|i| i.is_available())
            .collect()
    }

    /// The widest build this CPU runs, or the one `TESSERA_ISA` (portable, avx2, avx512)
    /// names if the CPU has it: for measuring one build against another.
    pub fn best() -> Isa {
        static BEST: std::sync::OnceLock<Isa> = std::sync::OnceLock::new();
        *BEST.get_or_init(|| {
            let asked = std::env::var("TESSERA_ISA")
                .ok()
                .and_then(|v| Isa::from_name(&v));
            match asked {
                Some(isa) if isa.is_available() => isa,
                _ => *Isa::available().last().unwrap_or(&Isa::Portable),
            }
        })
    }

    /// Which of an entry point's `builds` runs when `self` is asked for: if the CPU runs
    /// `self`, the widest of `builds` no wider than it, else (or if there is none) portable.
    /// An entry point lists only the builds that gain something: single rays, for example,
    /// have no AVX-512 build and run their AVX2 one on an AVX-512 CPU.
    #[inline]
    pub fn runnable_within(self, builds: &[Isa]) -> Runnable {
        // Once per traversal: the CPU's features read once, not each build's one by one.
        static AVAILABLE: std::sync::OnceLock<u8> = std::sync::OnceLock::new();
        let available = *AVAILABLE.get_or_init(|| {
            Isa::available()
                .into_iter()
                .fold(0, |bits, isa| bits | 1 << isa as u8)
        });
        let runs = |isa: Isa| available >> isa as u8 & 1 == 1;
        if !runs(self) {
            return Runnable::PORTABLE;
        }
        let widest = builds
            .iter()
            .copied()
            .filter(|&b| b <= self && runs(b))
            .max();
        Runnable(widest.unwrap_or(Isa::Portable))
    }

    pub fn from_name(name: &str) -> Option<Isa> {
        match name {
            "portable" => Some(Isa::Portable),
            "avx2" => Some(Isa::Avx2),
            "avx512" => Some(Isa::Avx512),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Isa::Portable => "portable",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }
}

/// A build that this CPU runs: made by [`Isa::runnable_within`], which checks, or by the builds
/// `isa_builds!` writes, which only run once it has. A kernel that holds one may use that
/// build's instructions: the single-ray traversal picks its AVX2 node test by it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Runnable(Isa);

impl Runnable {
    /// The baseline, which every CPU runs.
    pub const PORTABLE: Runnable = Runnable(Isa::Portable);

    /// `isa`, taken on trust.
    ///
    /// # Safety
    /// The CPU must run `isa` ([`Isa::is_available`]).
    #[inline(always)]
    pub const unsafe fn new_unchecked(isa: Isa) -> Runnable {
        Runnable(isa)
    }

    #[inline(always)]
    pub fn isa(self) -> Isa {
        self.0
    }
}

/// Declares an entry point with SIMD builds: a function `name(isa, args...)` that runs
/// `kernel(build, args...)` on the build [`Isa::runnable_within`] picks among those listed.
/// Each listed build is the kernel compiled with that ISA's target features (the kernel must
/// be `#[inline(always)]` so that it is compiled into each); portable is always there.
///
/// ```text
/// isa_builds! {
///     /// Which rays of a packet are blocked, on the build `isa`.
///     pub fn occluded_lanes_on<M: TreeMemory>(mem: &mut M, packet: &mut RayPacket) -> u64
///         = occluded_lanes_kernel on [Avx2, Avx512];
/// }
/// ```
macro_rules! isa_builds {
    (
        $(#[$attr:meta])*
        $vis:vis fn $name:ident<$($g:ident: $bound:path),*>($($arg:ident: $ty:ty),* $(,)?)
            $(-> $ret:ty)? = $kernel:ident on [$($build:ident),* $(,)?];
    ) => {
        $(#[$attr])*
        $vis fn $name<$($g: $bound),*>(isa: $crate::isa::Isa, $($arg: $ty),*) $(-> $ret)? {
            $crate::isa::isa_builds!(
                @builds [$($build)*] [$($g: $bound),*] ($($arg: $ty),*) [$(-> $ret)?] $kernel
            );
            #[cfg(target_arch = "x86_64")]
            $crate::isa::isa_builds!(@dispatch isa [$($build)*] ($($arg),*));
            #[cfg(not(target_arch = "x86_64"))]
            let _ = isa;
            $kernel($crate::isa::Runnable::PORTABLE, $($arg),*)
        }
    };
    (@builds [$($build:ident)*] $gens:tt $params:tt $ret:tt $kernel:ident) => {
        $($crate::isa::isa_builds!(@build $build $gens $params $ret $kernel);)*
    };
    (@build Avx2 $gens:tt $params:tt $ret:tt $kernel:ident) => {
        $crate::isa::isa_builds!(@build_with "avx2", Avx2 $gens $params $ret $kernel);
    };
    (@build Avx512 $gens:tt $params:tt $ret:tt $kernel:ident) => {
        $crate::isa::isa_builds!(
            @build_with "avx512f,avx512vl,avx512bw,avx512dq", Avx512 $gens $params $ret $kernel
        );
    };
    (
        @build_with $features:literal, $isa:ident [$($gens:tt)*] ($($arg:ident: $ty:ty),*)
        [$($ret:tt)*] $kernel:ident
    ) => {
        /// The kernel compiled for this build.
        ///
        /// # Safety
        /// The CPU must run this build (the dispatch calls it only once
        /// [`Isa::runnable_within`](crate::isa::Isa::runnable_within) has picked it).
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $features)]
        #[allow(non_snake_case)]
        unsafe fn $isa<$($gens)*>($($arg: $ty),*) $($ret)* {
            // SAFETY: this build runs only where the CPU has its features (see above).
            let build = unsafe { $crate::isa::Runnable::new_unchecked($crate::isa::Isa::$isa) };
            $kernel(build, $($arg),*)
        }
    };
    (@dispatch $isa:ident [$($build:ident)*] $args:tt) => {
        match $isa.runnable_within(&[$($crate::isa::Isa::$build),*]).isa() {
            $(
                $crate::isa::Isa::$build => {
                    return $crate::isa::isa_builds!(@call $build $args);
                }
            )*
            _ => {}
        }
    };
    (@call $build:ident ($($arg:ident),*)) => {
        // SAFETY: `runnable_within` picked this build, so the CPU runs it.
        unsafe { $build($($arg),*) }
    };
}
pub(crate) use isa_builds;
