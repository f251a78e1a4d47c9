//! Which SIMD build of the hot loops runs, chosen at run time: a wall's render nodes differ
//! (AVX2 on some, AVX-512 on others), and one binary serves them all. Every build runs the
//! same operations in the same order, and Rust never contracts a multiply and an add into an
//! FMA on its own, so all give bit-identical pixels; the tests check each against the portable
//! one on every machine they run on.

/// A build of the packet traversal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
