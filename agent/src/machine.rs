//! The kind of CPU a run or a timing is on. Timings compare only between like CPUs, and a
//! lockstep run repeats number for number only on one kind: the matrix kernels are chosen by
//! CPU, and different CPUs' kernels round differently
//! (docs/experiments/2026-12-07-one-seed-two-cpus.md).

/// This machine's CPU: its name and generation, how many logical cores this process may use,
/// and its widest vector instructions. None where /proc/cpuinfo names no model.
pub fn cpu_description() -> Option<String> {
    describe_cpu(&std::fs::read_to_string("/proc/cpuinfo").ok()?)
}

/// [`cpu_description`] from the text of /proc/cpuinfo.
pub fn describe_cpu(cpuinfo: &str) -> Option<String> {
    let field = |name: &str| {
        cpuinfo.lines().find_map(|line| {
            let (key, value) = line.split_once(':')?;
            (key.trim() == name).then(|| value.trim().to_owned())
        })
    };
    let model = field("model name")?;
    // Virtual machines often name every CPU of a vendor alike ("AMD EPYC"): the family and
    // model numbers tell generations apart. (Not the clock: /proc/cpuinfo gives the current
    // one, which moves on a machine that scales it.)
    let numbers =
        ["cpu family", "model", "stepping"].map(|name| field(name).unwrap_or_else(|| "?".into()));
    let flags = field("flags").unwrap_or_default();
    let has = |flag: &str| flags.split_whitespace().any(|f| f == flag);
    let vectors = match (has("avx512f"), has("avx512_bf16"), has("avx2")) {
        (true, true, _) => "AVX-512 with BF16",
        (true, false, _) => "AVX-512",
        (false, _, true) => "AVX2, no AVX-512",
        _ => "no AVX2",
    };
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let [family, number, stepping] = numbers;
    Some(format!(
        "{model} (family {family} model {number} stepping {stepping}), {cores} logical \
         cores, {vectors}"
    ))
}

#[cfg(test)]
mod tests {
    use super::describe_cpu;

    #[test]
    fn the_cpu_is_named_with_its_widest_vector_instructions() {
        let cpu = |flags: &str| {
            let info = format!(
                "processor\t: 0\ncpu family\t: 25\nmodel\t\t: 1\nmodel name\t: AMD EPYC\n\
                 stepping\t: 1\ncpu MHz\t\t: 2445.402\nflags\t\t: fpu {flags} sse2\n\n\
                 processor\t: 1\ncpu family\t: 25\nmodel\t\t: 1\nmodel name\t: AMD EPYC\n\
                 stepping\t: 1\ncpu MHz\t\t: 2445.402\nflags\t\t: fpu {flags} sse2\n"
            );
            describe_cpu(&info).unwrap()
        };
        assert!(cpu("avx2 avx512f avx512_bf16").ends_with("AVX-512 with BF16"));
        assert!(cpu("avx2 avx512f").ends_with("AVX-512"));
        assert!(cpu("avx avx2 fma").ends_with("AVX2, no AVX-512"));
        assert!(cpu("avx").ends_with("no AVX2"));
        assert!(
            cpu("avx2").starts_with("AMD EPYC (family 25 model 1 stepping 1), "),
            "{}",
            cpu("avx2")
        );
        assert_eq!(describe_cpu("processor\t: 0\n"), None);
    }
}
