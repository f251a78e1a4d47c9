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
    Portable = 0,
    /// 8-wide lanes.
    Avx2 = 1,
    /// 16-wide lanes (AVX-512 F, with VL, BW and DQ for the narrower operations).
    Avx512 = 2,
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
    /// have no AVX-512 build and run their AVX2 one on an AVX-512 CPU. The answer is always a
    /// build this CPU runs.
    #[inline]
    pub fn runnable_within(self, builds: &[Isa]) -> Isa {
        // Once per traversal: the CPU's features read once, not each build's one by one.
        static AVAILABLE: std::sync::OnceLock<u8> = std::sync::OnceLock::new();
        let available = *AVAILABLE.get_or_init(|| {
            Isa::available()
                .into_iter()
                .fold(0, |bits, isa| bits | 1 << isa as u8)
        });
        let runs = |isa: Isa| available >> isa as u8 & 1 == 1;
        if !runs(self) {
            return Isa::Portable;
        }
        let widest = builds
            .iter()
            .copied()
            .filter(|&b| b <= self && runs(b))
            .max();
        widest.unwrap_or(Isa::Portable)
    }

    /// The ISA [`Isa::name`] calls `name` (`portable`, `avx2`, `avx512`), if any.
    pub fn from_name(name: &str) -> Option<Isa> {
        match name {
            "portable" => Some(Isa::Portable),
            "avx2" => Some(Isa::Avx2),
            "avx512" => Some(Isa::Avx512),
            _ => None,
        }
    }

    /// The lower-case name `TESSERA_ISA` and reports give it.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Portable => "portable",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }
}

/// What [`Isa::runnable_within`] answered for one entry point, per ISA asked, so that a call
/// costs one load instead of the choice: single rays make it once per ray.
pub(crate) struct Picked([std::sync::atomic::AtomicU8; 3]);

impl Picked {
    const UNKNOWN: u8 = u8::MAX;

    pub(crate) const fn new() -> Self {
        Picked([const { std::sync::atomic::AtomicU8::new(Picked::UNKNOWN) }; 3])
    }

    /// [`Isa::runnable_within`], remembered.
    #[inline(always)]
    pub(crate) fn pick(&self, isa: Isa, builds: &[Isa]) -> Isa {
        use std::sync::atomic::Ordering::Relaxed;
        let slot = &self.0[isa as usize];
        match slot.load(Relaxed) {
            0 => Isa::Portable,
            1 => Isa::Avx2,
            2 => Isa::Avx512,
            _ => {
                let picked = isa.runnable_within(builds);
                slot.store(picked as u8, Relaxed);
                picked
            }
        }
    }
}

/// A build that this CPU runs, as a type: a kernel gets a value of one (`isa_builds!` hands
/// it over), and may use that build's instructions; the single-ray traversal picks its AVX2
/// node test by it. Being a type, each build is its own monomorphization of the kernel, closures
/// included, so each inlines into its `#[target_feature]` function as if written there.
///
/// # Safety
/// A value of an implementing type may exist only where the CPU runs [`Build::ISA`].
pub(crate) unsafe trait Build: Copy {
    const ISA: Isa;
}

/// The types of [`Build`], one per [`Isa`], named as its variants.
pub(crate) mod build {
    use super::{Build, Isa};

    /// The baseline, which every CPU runs.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Portable;

    /// AVX2, made only where the CPU has it.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Avx2(());

    /// AVX-512 (F, VL, BW, DQ), made only where the CPU has it.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Avx512(());

    impl Avx2 {
        /// The AVX2 build, without checking the CPU.
        ///
        /// # Safety
        /// The CPU must have AVX2.
        #[inline(always)]
        pub(crate) const unsafe fn new_unchecked() -> Self {
            Avx2(())
        }
    }

    impl Avx512 {
        /// The AVX-512 build, without checking the CPU.
        ///
        /// # Safety
        /// The CPU must have the AVX-512 features of [`Isa::Avx512`].
        #[inline(always)]
        pub(crate) const unsafe fn new_unchecked() -> Self {
            Avx512(())
        }
    }

    // SAFETY: every CPU runs the portable build.
    unsafe impl Build for Portable {
        const ISA: Isa = Isa::Portable;
    }

    // SAFETY: an `Avx2` is made only by `new_unchecked`, whose caller vouches for AVX2.
    unsafe impl Build for Avx2 {
        const ISA: Isa = Isa::Avx2;
    }

    // SAFETY: an `Avx512` is made only by `new_unchecked`, whose caller vouches for AVX-512.
    unsafe impl Build for Avx512 {
        const ISA: Isa = Isa::Avx512;
    }
}

/// Declares an entry point with SIMD builds: a function `name(isa, args...)` that runs
/// `kernel(build, args...)` on the build [`Isa::runnable_within`] picks among those listed
/// (`build` a value of that ISA's [`Build`] type).
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
            $kernel($crate::isa::build::Portable, $($arg),*)
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
            let build = unsafe { $crate::isa::build::$isa::new_unchecked() };
            $kernel(build, $($arg),*)
        }
    };
    (@dispatch $isa:ident [$($build:ident)*] $args:tt) => {
        static PICKED: $crate::isa::Picked = $crate::isa::Picked::new();
        match PICKED.pick($isa, &[$($crate::isa::Isa::$build),*]) {
            $(
                $crate::isa::Isa::$build => {
                    return $crate::isa::isa_builds!(@call $build $args);
                }
            )*
            _ => {}
        }
    };
    (@call $build:ident ($($arg:ident),*)) => {
        // SAFETY: `runnable_within` picked this build (now or on an earlier call), so the CPU
        // runs it.
        unsafe { $build($($arg),*) }
    };
}
pub(crate) use isa_builds;
