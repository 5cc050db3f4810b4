//! The instruction sets a binary was compiled for, checked against the CPU it runs on.
//!
//! The default build targets baseline x86-64 and picks wider code (the 8-wide BVH nodes, the
//! sampler's SSE4.1 multiply) at run time. A build for AVX2 CPUs (`RAYTILE_CPU=avx2`, see
//! `scripts/cpu-flags.sh`) lets the compiler use AVX2, BMI and LZCNT everywhere and renders
//! the same bits, as FMA stays off; but it stops with SIGILL on a CPU without them.
//!
//! So every program invokes [`cpu_gate!`]: a check that runs before `main` (an `.init_array`
//! entry, as C constructors are) and stops a binary on a CPU that lacks a feature it was
//! compiled for, with a message and exit status 1. The check is written in assembly
//! (`raytile_cpu_gate`): Rust code compiled for AVX2 uses AVX instructions
//! anywhere, even to copy sixteen bytes in `main`'s first lines, so no Rust function of such a
//! binary can be trusted to run on the CPU it is meant to refuse. The assembly asks the CPU
//! (`cpuid`, and `xgetbv` for the operating system's support of the AVX and AVX-512 registers,
//! as the standard library's `is_x86_feature_detected!` does) and writes its message with raw
//! `write` system calls:
//!
//! ```text
//! ./raytile: this binary was built for CPUs with sse3, ssse3, …, lzcnt, and this CPU lacks
//! avx, avx2, bmi1, bmi2, lzcnt: use the default build (it renders the same images)
//! ```
//!
//! `scripts/check-cpu-builds.sh --golden` runs a build for AVX2 on an emulated CPU without it
//! (`qemu-x86_64 -cpu Nehalem`) and checks that message.

/// The checked features, by the name both `cfg(target_feature)` and
/// `is_x86_feature_detected!` use, in the bit order of the assembly's mask.
macro_rules! feature_table {
    ($($name:tt),* $(,)?) => {
        /// The checked features, bit `i` of a mask being `NAMES[i]`.
        pub(crate) const NAMES: [&str; COUNT] = [$($name),*];

        /// Which of them this binary was compiled with (`-C target-feature=+...` or
        /// `-C target-cpu=...`).
        const COMPILED: [bool; COUNT] = [$(cfg!(target_feature = $name)),*];

        /// Which of them this CPU has, by the standard library's detection.
        #[cfg(target_arch = "x86_64")]
        fn detected() -> [bool; COUNT] {
            [$(std::arch::is_x86_feature_detected!($name)),*]
        }
    };
}

const COUNT: usize = 16;

// The assembly below tests each feature's CPUID bit in this order: keep them in step.
feature_table!(
    "sse3", "ssse3", "sse4.1", "sse4.2", "popcnt", "avx", "avx2", "bmi1", "bmi2", "lzcnt", "f16c",
    "fma", "avx512f", "avx512bw", "avx512dq", "avx512vl",
);

#[cfg(not(target_arch = "x86_64"))]
fn detected() -> [bool; COUNT] {
    [false; COUNT]
}

/// The features this binary was compiled for that this CPU lacks (none, once the gate let the
/// program start).
pub fn missing_features() -> Vec<&'static str> {
    let detected = detected();
    (0..COUNT)
        .filter(|&i| COMPILED[i] && !detected[i])
        .map(|i| NAMES[i])
        .collect()
}

/// The features this binary was compiled for (empty for the default build).
pub fn compiled_features() -> Vec<&'static str> {
    (0..COUNT)
        .filter(|&i| COMPILED[i])
        .map(|i| NAMES[i])
        .collect()
}

/// The mask of the features set in `flags`.
const fn mask(flags: &[bool; COUNT]) -> u32 {
    let mut m = 0;
    let mut i = 0;
    while i < COUNT {
        if flags[i] {
            m |= 1 << i;
        }
        i += 1;
    }
    m
}

/// Bytes of the message's longest part.
const TEXT: usize = 256;

/// `bytes` appended to `out[..len]`; returns the new length.
const fn append(out: &mut [u8; TEXT], mut len: usize, bytes: &[u8]) -> usize {
    let mut i = 0;
    while i < bytes.len() {
        out[len] = bytes[i];
        len += 1;
        i += 1;
    }
    len
}

/// What the gate writes after the program's name: `": this binary was built for CPUs with A,
/// B, and this CPU lacks"` for the features in `flags`; then come the missing features and
/// [`SUFFIX`].
const fn prefix(flags: &[bool; COUNT]) -> ([u8; TEXT], usize) {
    let mut out = [0u8; TEXT];
    let mut len = append(&mut out, 0, b": this binary was built for CPUs with");
    let mut first = true;
    let mut i = 0;
    while i < COUNT {
        if flags[i] {
            len = append(&mut out, len, if first { b" " } else { b", " });
            len = append(&mut out, len, NAMES[i].as_bytes());
            first = false;
        }
        i += 1;
    }
    len = append(&mut out, len, b", and this CPU lacks");
    (out, len)
}

/// The end of the gate's message.
const SUFFIX: &[u8] = b": use the default build (it renders the same images)\n";

/// Each feature's name in a 16-byte slot, its length in the last byte (what the assembly
/// reads).
const fn name_slots() -> [[u8; 16]; COUNT] {
    let mut slots = [[0u8; 16]; COUNT];
    let mut i = 0;
    while i < COUNT {
        let name = NAMES[i].as_bytes();
        assert!(name.len() < 16);
        let mut j = 0;
        while j < name.len() {
            slots[i][j] = name[j];
            j += 1;
        }
        slots[i][15] = name.len() as u8;
        i += 1;
    }
    slots
}

const PREFIX: ([u8; TEXT], usize) = prefix(&COMPILED);

/// The data the assembly reads, by symbol.
#[cfg(target_arch = "x86_64")]
mod gate_data {
    pub(super) static PREFIX_BYTES: [u8; super::TEXT] = super::PREFIX.0;
    pub(super) static SUFFIX_BYTES: [u8; super::SUFFIX.len()] = {
        let mut out = [0u8; super::SUFFIX.len()];
        let mut i = 0;
        while i < out.len() {
            out[i] = super::SUFFIX[i];
            i += 1;
        }
        out
    };
    pub(super) static NAME_SLOTS: [[u8; 16]; super::COUNT] = super::name_slots();
    /// " " before the first missing feature's name, ", " before the others.
    pub(super) static SEPARATORS: [u8; 3] = *b" , ";
}

// The gate's assembly: two functions.
//
// `raytile_cpu_have() -> u32`: the mask (bit `i` = `NAMES[i]`) of the features this CPU has
// and the operating system enables (AVX and its relatives need the AVX state in XCR0, the
// AVX-512 ones the opmask and upper-register states too).
//
// `raytile_cpu_gate(argc, argv, envp)`: returns if the CPU has every feature this binary was
// compiled for; otherwise writes `argv[0]` and the message to standard error and exits with
// status 1 (`exit_group`), before anything else of the program runs.
//
// No numeric label is made of the digits 0 and 1 alone (such as 10): Intel syntax could read
// `10b` as a binary number.
#[cfg(target_arch = "x86_64")]
std::arch::global_asm!(
    ".pushsection .text.raytile_cpu_have,\"ax\",@progbits",
    ".globl raytile_cpu_have",
    ".hidden raytile_cpu_have",
    ".type raytile_cpu_have,@function",
    "raytile_cpu_have:",
    "push rbx",
    // r9d: leaf 1 ECX; r10d: leaf 7 EBX; r11d: leaf 0x80000001 ECX; esi: XCR0.
    "xor eax, eax",
    "xor ecx, ecx",
    "cpuid",
    "mov edi, eax",
    "mov eax, 1",
    "xor ecx, ecx",
    "cpuid",
    "mov r9d, ecx",
    "xor r10d, r10d",
    "cmp edi, 7",
    "jb 2f",
    "mov eax, 7",
    "xor ecx, ecx",
    "cpuid",
    "mov r10d, ebx",
    "2:",
    "mov eax, 0x80000000",
    "xor ecx, ecx",
    "cpuid",
    "xor r11d, r11d",
    "cmp eax, 0x80000001",
    "jb 3f",
    "mov eax, 0x80000001",
    "xor ecx, ecx",
    "cpuid",
    "mov r11d, ecx",
    "3:",
    "xor esi, esi",
    "bt r9d, 27", // OSXSAVE: xgetbv may be used
    "jnc 4f",
    "xor ecx, ecx",
    "xgetbv",
    "mov esi, eax",
    "4:",
    "xor r8d, r8d",
    // Bit `bit` of register `reg` to bit `pos` of r8d, for each feature in NAMES' order.
    ".macro raytile_feature reg, bit, pos",
    "mov eax, \\reg",
    "shr eax, \\bit",
    "and eax, 1",
    "shl eax, \\pos",
    "or r8d, eax",
    ".endm",
    "raytile_feature r9d, 0, 0",   // sse3
    "raytile_feature r9d, 9, 1",   // ssse3
    "raytile_feature r9d, 19, 2",  // sse4.1
    "raytile_feature r9d, 20, 3",  // sse4.2
    "raytile_feature r9d, 23, 4",  // popcnt
    "raytile_feature r9d, 28, 5",  // avx
    "raytile_feature r10d, 5, 6",  // avx2
    "raytile_feature r10d, 3, 7",  // bmi1
    "raytile_feature r10d, 8, 8",  // bmi2
    "raytile_feature r11d, 5, 9",  // lzcnt (ABM)
    "raytile_feature r9d, 29, 10", // f16c
    "raytile_feature r9d, 12, 11", // fma
    "raytile_feature r10d, 16, 12", // avx512f
    "raytile_feature r10d, 30, 13", // avx512bw
    "raytile_feature r10d, 17, 14", // avx512dq
    "raytile_feature r10d, 31, 15", // avx512vl
    ".purgem raytile_feature",
    // Without the XMM and YMM states enabled: no AVX, AVX2, F16C, FMA nor AVX-512.
    "mov eax, esi",
    "and eax, 6",
    "cmp eax, 6",
    "je 5f",
    "and r8d, {no_avx}",
    "5:",
    // Without the opmask, ZMM_Hi256 and Hi16_ZMM states too: no AVX-512.
    "mov eax, esi",
    "and eax, 0xe6",
    "cmp eax, 0xe6",
    "je 6f",
    "and r8d, {no_avx512}",
    "6:",
    "mov eax, r8d",
    "pop rbx",
    "ret",
    ".size raytile_cpu_have, . - raytile_cpu_have",
    ".popsection",
    //
    ".pushsection .text.raytile_cpu_gate,\"ax\",@progbits",
    ".globl raytile_cpu_gate",
    ".hidden raytile_cpu_gate",
    ".type raytile_cpu_gate,@function",
    "raytile_cpu_gate:",
    "push rbx",
    "push r12",
    "push r13",
    "push r14",
    "push r15",
    "mov r15, rsi", // argv
    "call raytile_cpu_have",
    "not eax",
    "and eax, {required}",
    "jnz 7f",
    "pop r15",
    "pop r14",
    "pop r13",
    "pop r12",
    "pop rbx",
    "ret",
    "7:",
    "mov r12d, eax", // the missing features
    // argv[0], if there is one.
    "test r15, r15",
    "jz 8f",
    "mov rsi, [r15]",
    "test rsi, rsi",
    "jz 8f",
    "mov rdx, rsi",
    "9:",
    "cmp byte ptr [rdx], 0",
    "je 22f",
    "inc rdx",
    "jmp 9b",
    "22:",
    "sub rdx, rsi",
    "mov edi, 2",
    "mov eax, 1", // write
    "syscall",
    "8:",
    "lea rsi, [rip + {prefix}]",
    "mov edx, {prefix_len}",
    "mov edi, 2",
    "mov eax, 1",
    "syscall",
    // The missing features' names, " " before the first and ", " before the others.
    "lea r13, [rip + {names}]",
    "lea r14, [rip + {separators}]",
    "mov r15d, 1",
    "xor ebx, ebx",
    "23:",
    "bt r12d, ebx",
    "jnc 24f",
    "mov rsi, r14",
    "mov edx, r15d",
    "mov edi, 2",
    "mov eax, 1",
    "syscall",
    "mov rsi, rbx",
    "shl rsi, 4",
    "add rsi, r13",
    "movzx edx, byte ptr [rsi + 15]",
    "mov edi, 2",
    "mov eax, 1",
    "syscall",
    "lea r14, [rip + {separators} + 1]",
    "mov r15d, 2",
    "24:",
    "inc ebx",
    "cmp ebx, {count}",
    "jb 23b",
    "lea rsi, [rip + {suffix}]",
    "mov edx, {suffix_len}",
    "mov edi, 2",
    "mov eax, 1",
    "syscall",
    "mov edi, 1",
    "mov eax, 231", // exit_group
    "syscall",
    "ud2",
    ".size raytile_cpu_gate, . - raytile_cpu_gate",
    ".popsection",
    no_avx = const !(1u32 << 5 | 1 << 6 | 1 << 10 | 1 << 11 | 0xf << 12),
    no_avx512 = const !(0xfu32 << 12),
    required = const mask(&COMPILED),
    prefix = sym gate_data::PREFIX_BYTES,
    prefix_len = const PREFIX.1,
    names = sym gate_data::NAME_SLOTS,
    separators = sym gate_data::SEPARATORS,
    count = const COUNT,
    suffix = sym gate_data::SUFFIX_BYTES,
    suffix_len = const SUFFIX.len(),
);

#[cfg(target_arch = "x86_64")]
extern "C" {
    #[cfg(test)]
    fn raytile_cpu_have() -> u32;
    /// The check [`cpu_gate!`] runs before `main` (see the module's documentation).
    pub fn raytile_cpu_gate(argc: i32, argv: *const *const u8, envp: *const *const u8);
}

/// Stops the program before `main`, with a message and exit status 1, on a CPU that lacks an
/// instruction set the binary was compiled for (see [`crate::cpu`]). Invoke it once, at the
/// top level of each program's crate root.
#[macro_export]
macro_rules! cpu_gate {
    () => {
        #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
        #[used]
        #[link_section = ".init_array"]
        static RAYTILE_CPU_GATE: unsafe extern "C" fn(i32, *const *const u8, *const *const u8) =
            $crate::cpu::raytile_cpu_gate;
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_running_binary_fits_its_cpu() {
        assert!(missing_features().is_empty());
        #[cfg(target_arch = "x86_64")]
        assert_eq!(
            compiled_features().contains(&"avx2"),
            cfg!(target_feature = "avx2")
        );
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_gates_detection_is_the_standard_librarys() {
        // SAFETY: `raytile_cpu_have` only runs cpuid (and xgetbv where the CPU allows it).
        let have = unsafe { raytile_cpu_have() };
        let detected = detected();
        for (i, name) in NAMES.iter().enumerate() {
            assert_eq!(have >> i & 1 == 1, detected[i], "{name}");
        }
    }

    #[test]
    fn the_message_names_what_the_binary_was_built_for() {
        let mut flags = [false; COUNT];
        for name in ["avx2", "sse4.1", "bmi2"] {
            flags[NAMES.iter().position(|n| *n == name).unwrap()] = true;
        }
        let (bytes, len) = prefix(&flags);
        assert_eq!(
            std::str::from_utf8(&bytes[..len]).unwrap(),
            ": this binary was built for CPUs with sse4.1, avx2, bmi2, and this CPU lacks"
        );
        assert_eq!(mask(&flags), 1 << 2 | 1 << 6 | 1 << 8);
        let slots = name_slots();
        for (slot, name) in slots.iter().zip(NAMES) {
            assert_eq!(&slot[..usize::from(slot[15])], name.as_bytes());
        }
    }
}
