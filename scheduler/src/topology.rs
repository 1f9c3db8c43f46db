//! Machine topology and thread placement.
//!
//! [`Topology::detect`] asks hwloc (crate `hwloc2`) for packages, cores, PUs and caches; where hwloc is not
//! available it falls back to `/sys/devices/system/cpu` and `std::thread::available_parallelism`. NUMA nodes
//! are counted through the root object's node set: hwloc2's NUMA-object walk is not safe with hwloc 2.x.
//!
//! [`placement`] maps `P` virtual processes × `T` threads (worker index `p * T + t`, process-major) to cores
//! under a [`PinPolicy`]. "Core" here always means the OS index of a processing unit, the number that
//! `core_affinity`, `taskset` and `/proc/cpuinfo` use. Compact and scatter place at most one worker on each
//! physical core (on its first PU) before they wrap around; SMT siblings are not used.

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;
use std::sync::OnceLock;

/// What hwloc reports about the machine.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Topology {
    /// Physical packages (sockets).
    pub packages: usize,
    /// NUMA nodes (1 on a machine without NUMA information).
    pub numa_nodes: usize,
    /// Physical cores.
    pub cores: usize,
    /// Processing units (hardware threads).
    pub pus: usize,
    /// Each L3 cache: its size in bytes and the OS indices of the PUs that share it, in topology order.
    pub l3_caches: Vec<(usize, Vec<usize>)>,
    /// Size of one L2 cache in bytes, if known.
    pub l2_bytes: Option<usize>,
    /// PU os index of each core's first PU, in topology order (package, core).
    pub core_pus: Vec<usize>,
    /// CPU model name (from `/proc/cpuinfo`), or `"unknown"`.
    pub model: String,
}

impl Topology {
    /// Detects the machine: hwloc first, then `/sys` and `available_parallelism` if hwloc cannot load a
    /// topology. Never panics and always reports at least one core.
    pub fn detect() -> Topology {
        let hw = std::panic::catch_unwind(detect_hwloc).ok().flatten();
        let mut topo = hw.unwrap_or_else(detect_fallback);
        topo.model = cpu_model();
        topo
    }

    /// Human-readable multi-line description (model, counts, caches, cores).
    pub fn describe(&self) -> String {
        let mut s = String::new();
        s.push_str(&format!("model: {}\n", self.model));
        s.push_str(&format!(
            "packages: {}, NUMA nodes: {}, cores: {}, PUs: {}{}\n",
            self.packages,
            self.numa_nodes,
            self.cores,
            self.pus,
            if self.pus > self.cores {
                format!(" ({} PUs per core)", self.pus / self.cores.max(1))
            } else {
                String::new()
            }
        ));
        if self.l3_caches.is_empty() {
            s.push_str("L3: none reported\n");
        }
        for (i, (bytes, pus)) in self.l3_caches.iter().enumerate() {
            s.push_str(&format!(
                "L3 #{i}: {}, shared by PUs {}\n",
                format_bytes(*bytes),
                format_core_list(pus)
            ));
        }
        match self.l2_bytes {
            Some(b) => s.push_str(&format!("L2: {} each\n", format_bytes(b))),
            None => s.push_str("L2: not reported\n"),
        }
        s.push_str(&format!(
            "cores (first PU, topology order): {}\n",
            format_core_list(&self.core_pus)
        ));
        s
    }
}

/// Reads the topology through hwloc; `None` if hwloc cannot load one.
fn detect_hwloc() -> Option<Topology> {
    use hwloc2::ObjectType;
    let topo = hwloc2::Topology::new()?;
    let objects = |ty: ObjectType| -> Vec<&hwloc2::TopologyObject> {
        match topo.depth_for_type(&ty) {
            Ok(d) if d < topo.depth() => topo.objects_at_depth(d),
            _ => Vec::new(),
        }
    };
    let first_pu = |o: &hwloc2::TopologyObject| -> Option<usize> {
        let first = o.cpuset()?.first();
        (first >= 0).then_some(first as usize)
    };
    let pu_objs = objects(ObjectType::PU);
    if pu_objs.is_empty() {
        return None;
    }
    let pus = pu_objs.len();
    let mut core_pus: Vec<usize> = objects(ObjectType::Core).into_iter().filter_map(first_pu).collect();
    if core_pus.is_empty() {
        core_pus = pu_objs.into_iter().filter_map(first_pu).collect();
    }
    let packages = objects(ObjectType::Package).len().max(1);
    // Never walk NUMA objects (hwloc2's walk panics with hwloc 2.x): count the root's node set instead.
    let numa_nodes = topo
        .objects_at_depth(0)
        .first()
        .and_then(|root| root.nodeset())
        .map(|ns| ns.weight())
        .filter(|&w| w > 0)
        .map_or(1, |w| w as usize);
    let l3_caches = objects(ObjectType::L3Cache)
        .into_iter()
        .map(|o| {
            let bytes = o.cache_attributes().map_or(0, |c| c.size() as usize);
            let pus = o
                .cpuset()
                .map(|c| c.into_iter().map(|p| p as usize).collect())
                .unwrap_or_default();
            (bytes, pus)
        })
        .collect();
    let l2_bytes = objects(ObjectType::L2Cache)
        .first()
        .and_then(|o| o.cache_attributes())
        .map(|c| c.size() as usize)
        .filter(|&b| b > 0);
    Some(Topology {
        packages,
        numa_nodes,
        cores: core_pus.len(),
        pus,
        l3_caches,
        l2_bytes,
        core_pus,
        model: String::new(),
    })
}

/// Reads the topology from `/sys/devices/system/cpu`, or assumes `available_parallelism` single-PU cores in
/// one package.
fn detect_fallback() -> Topology {
    let sys = std::path::Path::new("/sys/devices/system/cpu");
    let read = |rel: String| {
        std::fs::read_to_string(sys.join(rel))
            .ok()
            .map(|s| s.trim().to_string())
    };
    let online = read("online".into())
        .and_then(|s| parse_core_list(&s).ok())
        .filter(|v| !v.is_empty());
    let online = online.unwrap_or_else(|| {
        let n = std::thread::available_parallelism().map_or(1, |n| n.get());
        (0..n).collect()
    });
    // (package, core id) -> PUs of that core.
    let mut cores: BTreeMap<(usize, usize), Vec<usize>> = BTreeMap::new();
    for &cpu in &online {
        let num = |f: &str| read(format!("cpu{cpu}/topology/{f}")).and_then(|s| s.parse::<usize>().ok());
        let pkg = num("physical_package_id").unwrap_or(0);
        let core = num("core_id").unwrap_or(cpu);
        cores.entry((pkg, core)).or_default().push(cpu);
    }
    let mut core_list: Vec<(usize, usize)> = cores.iter().map(|(&(pkg, _), pus)| (pkg, pus[0])).collect();
    core_list.sort_unstable();
    let packages = core_list
        .iter()
        .map(|c| c.0)
        .collect::<std::collections::BTreeSet<_>>()
        .len()
        .max(1);
    let mut l3_caches: Vec<(usize, Vec<usize>)> = Vec::new();
    let mut l2_bytes = None;
    for &cpu in &online {
        for index in 0..8 {
            let base = format!("cpu{cpu}/cache/index{index}");
            let Some(level) = read(format!("{base}/level")) else {
                break;
            };
            let kind = read(format!("{base}/type")).unwrap_or_default();
            if kind == "Instruction" {
                continue;
            }
            let bytes = read(format!("{base}/size")).and_then(|s| parse_size(&s)).unwrap_or(0);
            if level == "2" && l2_bytes.is_none() && bytes > 0 {
                l2_bytes = Some(bytes);
            }
            if level == "3" {
                let shared = read(format!("{base}/shared_cpu_list")).and_then(|s| parse_core_list(&s).ok());
                let shared = shared.unwrap_or_else(|| vec![cpu]);
                if !l3_caches.iter().any(|(_, pus)| pus.contains(&cpu)) {
                    l3_caches.push((bytes, shared));
                }
            }
        }
    }
    Topology {
        packages,
        numa_nodes: 1,
        cores: core_list.len(),
        pus: online.len(),
        l3_caches,
        l2_bytes,
        core_pus: core_list.into_iter().map(|c| c.1).collect(),
        model: String::new(),
    }
}

/// "model name" (or "Processor"/"cpu model") of the first CPU in `/proc/cpuinfo`, or `"unknown"`.
fn cpu_model() -> String {
    let text = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    for key in ["model name", "Processor", "cpu model", "uarch"] {
        for line in text.lines() {
            if let Some((k, v)) = line.split_once(':') {
                if k.trim() == key && !v.trim().is_empty() {
                    return v.trim().to_string();
                }
            }
        }
    }
    "unknown".to_string()
}

/// Parses a cache size such as `512K`, `32M` or `1048576`.
fn parse_size(s: &str) -> Option<usize> {
    let s = s.trim();
    let (num, mul) = match s.chars().last()? {
        'K' | 'k' => (&s[..s.len() - 1], 1usize << 10),
        'M' | 'm' => (&s[..s.len() - 1], 1 << 20),
        'G' | 'g' => (&s[..s.len() - 1], 1 << 30),
        _ => (s, 1),
    };
    num.trim().parse::<usize>().ok().and_then(|n| n.checked_mul(mul))
}

fn format_bytes(b: usize) -> String {
    if b >= 1 << 20 && b.is_multiple_of(1 << 20) {
        format!("{} MiB", b >> 20)
    } else if b >= 1 << 10 && b.is_multiple_of(1 << 10) {
        format!("{} KiB", b >> 10)
    } else {
        format!("{b} B")
    }
}

/// Formats core numbers as a compact list with ranges, e.g. `0-3,8,10-11` (in the given order; runs of
/// consecutive numbers become ranges).
pub fn format_core_list(cores: &[usize]) -> String {
    let mut parts = Vec::new();
    let mut i = 0;
    while i < cores.len() {
        let mut j = i;
        while j + 1 < cores.len() && cores[j + 1] == cores[j] + 1 {
            j += 1;
        }
        parts.push(if j > i {
            format!("{}-{}", cores[i], cores[j])
        } else {
            cores[i].to_string()
        });
        i = j + 1;
    }
    parts.join(",")
}

/// Largest core number a pin list may name (keeps `0-99999999999` from allocating the world).
const MAX_CORE: usize = 1 << 16;

/// Parses `0,2,4-7` into `[0, 2, 4, 5, 6, 7]`; the error names the bad token.
fn parse_core_list(s: &str) -> Result<Vec<usize>, String> {
    let mut out = Vec::new();
    let num = |tok: &str, part: &str| -> Result<usize, String> {
        let n: usize = part.trim().parse().map_err(|_| {
            format!(
                "bad token \"{tok}\" in core list \"{s}\": expected a core number or a range like 4-7 \
                 (or one of none, compact, scatter)"
            )
        })?;
        if n >= MAX_CORE {
            return Err(format!(
                "bad token \"{tok}\" in core list \"{s}\": core numbers must be below {MAX_CORE}"
            ));
        }
        Ok(n)
    };
    for tok in s.split(',') {
        let tok = tok.trim();
        if tok.is_empty() {
            return Err(format!("empty token in core list \"{s}\": expected e.g. 0,2,4-7"));
        }
        match tok.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (num(tok, a)?, num(tok, b)?);
                if a > b {
                    return Err(format!(
                        "bad range \"{tok}\" in core list \"{s}\": {a} is larger than {b}"
                    ));
                }
                out.extend(a..=b);
            }
            None => out.push(num(tok, tok)?),
        }
    }
    Ok(out)
}

/// Pinning policy for the worker threads.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum PinPolicy {
    /// No pinning: the OS places threads.
    #[default]
    None,
    /// Fill cores in topology order; the threads of a process sit on adjacent cores.
    Compact,
    /// Spread processes round-robin over packages / L3 domains; threads of a process adjacent in its domain.
    Scatter,
    /// Explicit cores (OS indices), one per worker in worker order.
    List(Vec<usize>),
}

impl FromStr for PinPolicy {
    type Err = String;

    /// `"none"`, `"compact"`, `"scatter"` (any case) or a core list such as `"0,2,4-7"`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "none" => Ok(PinPolicy::None),
            "compact" => Ok(PinPolicy::Compact),
            "scatter" => Ok(PinPolicy::Scatter),
            "" => Err("empty pin policy: use none, compact, scatter or a core list like 0,2,4-7".to_string()),
            _ => parse_core_list(s).map(PinPolicy::List),
        }
    }
}

impl fmt::Display for PinPolicy {
    /// The string [`PinPolicy::from_str`] parses back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PinPolicy::None => f.write_str("none"),
            PinPolicy::Compact => f.write_str("compact"),
            PinPolicy::Scatter => f.write_str("scatter"),
            PinPolicy::List(cores) => f.write_str(&format_core_list(cores)),
        }
    }
}

static ALLOWED_CORES: OnceLock<Vec<usize>> = OnceLock::new();

/// The cores (PU OS indices, ascending) this process may use. Read once, from the affinity mask of the
/// thread that first calls this or [`init_allowed_cores`] (core_affinity reports the *calling thread's*
/// mask), so call [`init_allowed_cores`] early in `main`, before any thread is pinned. Falls back to
/// `0..available_parallelism` if the mask cannot be read.
pub fn allowed_cores() -> Vec<usize> {
    ALLOWED_CORES
        .get_or_init(|| {
            let mut cores: Vec<usize> = core_affinity::get_core_ids()
                .map(|ids| ids.into_iter().map(|c| c.id).collect())
                .unwrap_or_default();
            if cores.is_empty() {
                let n = std::thread::available_parallelism().map_or(1, |n| n.get());
                cores = (0..n).collect();
            }
            cores.sort_unstable();
            cores.dedup();
            cores
        })
        .clone()
}

/// Reads and caches [`allowed_cores`] now; call it on the un-pinned main thread before starting workers.
pub fn init_allowed_cores() {
    let _ = allowed_cores();
}

/// Core for each worker (`p * threads + t`) of `processes` × `threads`, or `None` where it is not pinned.
///
/// - `None`: all `None`.
/// - `Compact`: the topology's cores (first PU of each core) that are allowed, in topology order; threads of
///   a process adjacent, and moved to the start of the next L3/package domain when that keeps a process
///   inside one domain without leaving cores unused.
/// - `Scatter`: process `p` goes to domain `p mod D` (L3 domains, or packages when no L3 is reported,
///   ordered so that consecutive domains alternate packages); its threads take adjacent free cores there,
///   spilling into the following domains when it is full.
/// - `List`: the listed cores in order (error if shorter than `processes * threads` or naming a core not
///   in [`allowed_cores`]).
///
/// When `processes * threads` exceeds the allowed cores, compact and scatter wrap around (oversubscription;
/// [`describe_placement`] reports it).
///
/// # Errors
/// A message if `processes` or `threads` is 0, the product is absurdly large, a core list is too short or
/// names a core this process may not use, or no core is allowed at all.
pub fn placement(
    topo: &Topology,
    processes: usize,
    threads: usize,
    policy: &PinPolicy,
) -> Result<Vec<Option<usize>>, String> {
    placement_with(topo, processes, threads, policy, &allowed_cores())
}

/// [`placement`] against an explicit set of allowed cores.
fn placement_with(
    topo: &Topology,
    processes: usize,
    threads: usize,
    policy: &PinPolicy,
    allowed: &[usize],
) -> Result<Vec<Option<usize>>, String> {
    if processes == 0 || threads == 0 {
        return Err(format!(
            "cannot place {processes} processes x {threads} threads: both must be at least 1"
        ));
    }
    let total = processes
        .checked_mul(threads)
        .filter(|&n| n <= 1 << 24)
        .ok_or_else(|| format!("{processes} processes x {threads} threads is too many workers"))?;
    match policy {
        PinPolicy::None => Ok(vec![None; total]),
        PinPolicy::List(list) => {
            if list.len() < total {
                return Err(format!(
                    "pin list {} names {} cores but {processes} processes x {threads} threads need {total}",
                    format_core_list(list),
                    list.len()
                ));
            }
            if let Some(bad) = list.iter().find(|c| !allowed.contains(c)) {
                return Err(format!(
                    "pin list names core {bad}, which this process may not use (allowed: {})",
                    format_core_list(allowed)
                ));
            }
            Ok(list[..total].iter().map(|&c| Some(c)).collect())
        }
        PinPolicy::Compact | PinPolicy::Scatter => {
            let domains = domains(topo, allowed);
            if domains.is_empty() {
                return Err("no allowed core to pin to".to_string());
            }
            let cores = if *policy == PinPolicy::Compact {
                compact(&domains, processes, threads)
            } else {
                scatter(&domains, processes, threads)
            };
            Ok(cores.into_iter().map(Some).collect())
        }
    }
}

/// Allowed cores grouped into L3 (or package) domains, each in topology order, domains in topology order.
fn domains(topo: &Topology, allowed: &[usize]) -> Vec<(usize, Vec<usize>)> {
    let n = topo.core_pus.len();
    let mut cores: Vec<(usize, usize)> = topo
        .core_pus
        .iter()
        .enumerate()
        .filter(|(_, pu)| allowed.contains(pu))
        .map(|(i, &pu)| (i * topo.packages.max(1) / n.max(1), pu))
        .collect();
    if cores.is_empty() {
        // The allowed PUs are none of the cores' first PUs (e.g. only SMT siblings): use them as they are.
        cores = allowed.iter().map(|&pu| (0, pu)).collect();
    }
    // Domain key: (package, L3 index); consecutive cores with the same key form one domain.
    let mut out: Vec<((usize, usize), Vec<usize>)> = Vec::new();
    for (pkg, pu) in cores {
        let l3 = topo
            .l3_caches
            .iter()
            .position(|(_, pus)| pus.contains(&pu))
            .unwrap_or(usize::MAX);
        match out.last_mut() {
            Some((key, list)) if *key == (pkg, l3) => list.push(pu),
            _ => out.push(((pkg, l3), vec![pu])),
        }
    }
    out.into_iter().map(|((pkg, _), list)| (pkg, list)).collect()
}

/// Compact: fill in order, skipping to the next domain when a process would straddle two domains and the
/// skip costs no core; wrap around when oversubscribed.
fn compact(domains: &[(usize, Vec<usize>)], processes: usize, threads: usize) -> Vec<usize> {
    let cores: Vec<usize> = domains.iter().flat_map(|d| d.1.iter().copied()).collect();
    let n = cores.len();
    let total = processes * threads;
    if total > n {
        return (0..total).map(|w| cores[w % n]).collect();
    }
    // End (exclusive) of the domain run containing each position.
    let mut run_end = vec![0; n];
    let mut start = 0;
    for d in domains {
        let end = start + d.1.len();
        run_end[start..end].fill(end);
        start = end;
    }
    let mut out = Vec::with_capacity(total);
    let mut pos = 0;
    for p in 0..processes {
        let straddles = pos + threads > run_end[pos];
        let next = run_end[pos];
        if straddles && next < n && run_end[next] - next >= threads && n - next >= threads * (processes - p) {
            pos = next;
        }
        out.extend_from_slice(&cores[pos..pos + threads]);
        pos += threads;
    }
    out
}

/// Scatter: process `p` starts in domain `p mod D` (domains interleaved across packages) and takes the
/// least-used cores, nearest domain first, lowest position first, never a core it already has while
/// another is available.
fn scatter(domains: &[(usize, Vec<usize>)], processes: usize, threads: usize) -> Vec<usize> {
    // Interleave packages: the r-th domain of every package, for r = 0, 1, ...
    let mut by_pkg: BTreeMap<usize, Vec<&Vec<usize>>> = BTreeMap::new();
    for (pkg, list) in domains {
        by_pkg.entry(*pkg).or_default().push(list);
    }
    let rounds = by_pkg.values().map(Vec::len).max().unwrap_or(0);
    let mut order: Vec<&Vec<usize>> = Vec::new();
    for r in 0..rounds {
        order.extend(by_pkg.values().filter_map(|v| v.get(r).copied()));
    }
    let d_count = order.len();
    let mut used: Vec<Vec<usize>> = order.iter().map(|d| vec![0; d.len()]).collect();
    let mut out = Vec::with_capacity(processes * threads);
    for p in 0..processes {
        let home = p % d_count;
        let mut mine: Vec<usize> = Vec::with_capacity(threads);
        for _ in 0..threads {
            // Key: (already mine, times used, domain distance, position in domain); then domain, position.
            type Candidate = ((bool, usize, usize, usize), usize, usize);
            let mut best: Option<Candidate> = None;
            for dist in 0..d_count {
                let d = (home + dist) % d_count;
                for (i, &core) in order[d].iter().enumerate() {
                    let key = (mine.contains(&core), used[d][i], dist, i);
                    if best.is_none_or(|(k, _, _)| key < k) {
                        best = Some((key, d, i));
                    }
                }
            }
            if let Some((_, d, i)) = best {
                used[d][i] += 1;
                mine.push(order[d][i]);
            }
        }
        out.extend(mine);
    }
    out
}

/// Text table of a placement (worker, process, thread, core or `-`), plus a warning line if any core hosts
/// more than one worker.
pub fn describe_placement(processes: usize, threads: usize, cores: &[Option<usize>]) -> String {
    let mut s = format!("{:>6} {:>7} {:>6} {:>5}\n", "worker", "process", "thread", "core");
    let t = threads.max(1);
    for (w, core) in cores.iter().enumerate() {
        let core = core.map_or_else(|| "-".to_string(), |c| c.to_string());
        s.push_str(&format!("{w:>6} {:>7} {:>6} {core:>5}\n", w / t, w % t));
    }
    if cores.len() != processes * threads {
        s.push_str(&format!(
            "warning: {} workers listed for {processes} processes x {threads} threads\n",
            cores.len()
        ));
    }
    let mut count: BTreeMap<usize, usize> = BTreeMap::new();
    for c in cores.iter().flatten() {
        *count.entry(*c).or_default() += 1;
    }
    let shared: Vec<String> = count
        .iter()
        .filter(|(_, &n)| n > 1)
        .map(|(c, n)| format!("core {c} hosts {n} workers"))
        .collect();
    if !shared.is_empty() {
        s.push_str(&format!(
            "warning: oversubscribed, {} pinned workers on {} cores: {}\n",
            cores.iter().flatten().count(),
            count.len(),
            shared.join(", ")
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 2 packages x 4 cores x 2 PUs; core i has PUs i and i + 8; one L3 per package.
    fn two_by_four() -> Topology {
        Topology {
            packages: 2,
            numa_nodes: 2,
            cores: 8,
            pus: 16,
            l3_caches: vec![
                (32 << 20, vec![0, 1, 2, 3, 8, 9, 10, 11]),
                (32 << 20, vec![4, 5, 6, 7, 12, 13, 14, 15]),
            ],
            l2_bytes: Some(1 << 20),
            core_pus: (0..8).collect(),
            model: "synthetic".into(),
        }
    }

    fn place(p: usize, t: usize, policy: &str) -> Result<Vec<usize>, String> {
        let allowed: Vec<usize> = (0..16).collect();
        let policy: PinPolicy = policy.parse()?;
        placement_with(&two_by_four(), p, t, &policy, &allowed).map(|v| v.into_iter().map(|c| c.unwrap()).collect())
    }

    #[test]
    fn parses_policies_and_lists() {
        assert_eq!("none".parse::<PinPolicy>(), Ok(PinPolicy::None));
        assert_eq!(" Compact ".parse::<PinPolicy>(), Ok(PinPolicy::Compact));
        assert_eq!("SCATTER".parse::<PinPolicy>(), Ok(PinPolicy::Scatter));
        assert_eq!(
            "0,2,4-7".parse::<PinPolicy>(),
            Ok(PinPolicy::List(vec![0, 2, 4, 5, 6, 7]))
        );
        assert_eq!("3".parse::<PinPolicy>(), Ok(PinPolicy::List(vec![3])));
        assert_eq!("1, 3 ,5-5".parse::<PinPolicy>(), Ok(PinPolicy::List(vec![1, 3, 5])));
        let e = "0,x,2".parse::<PinPolicy>().unwrap_err();
        assert!(e.contains("\"x\""), "{e}");
        let e = "0,2-a".parse::<PinPolicy>().unwrap_err();
        assert!(e.contains("\"2-a\""), "{e}");
        let e = "5-3".parse::<PinPolicy>().unwrap_err();
        assert!(e.contains("\"5-3\""), "{e}");
        assert!("0,,1".parse::<PinPolicy>().unwrap_err().contains("empty"));
        assert!("".parse::<PinPolicy>().is_err());
        assert!("compactt".parse::<PinPolicy>().unwrap_err().contains("\"compactt\""));
        assert!("-1".parse::<PinPolicy>().is_err());
        assert!("0-99999999999".parse::<PinPolicy>().is_err());
        for p in ["none", "compact", "scatter", "0,2,4-7"] {
            assert_eq!(p.parse::<PinPolicy>().unwrap().to_string(), p);
        }
    }

    #[test]
    fn compact_placements() {
        assert_eq!(place(1, 4, "compact").unwrap(), vec![0, 1, 2, 3]);
        assert_eq!(place(4, 2, "compact").unwrap(), vec![0, 1, 2, 3, 4, 5, 6, 7]);
        // A second 3-thread process would straddle the L3 boundary at core 4: it moves to 4..7.
        assert_eq!(place(2, 3, "compact").unwrap(), vec![0, 1, 2, 4, 5, 6]);
        // Three 2-thread processes fit without straddling anyway.
        assert_eq!(place(3, 2, "compact").unwrap(), vec![0, 1, 2, 3, 4, 5]);
        // Domains 0-2 | 4-6: skipping core 2 would leave too few cores, so the second process straddles.
        let allowed = [0, 1, 2, 4, 5, 6];
        let got = placement_with(&two_by_four(), 3, 2, &PinPolicy::Compact, &allowed).unwrap();
        assert_eq!(got, [0, 1, 2, 4, 5, 6].map(Some).to_vec());
        let got = placement_with(&two_by_four(), 2, 3, &PinPolicy::Compact, &allowed).unwrap();
        assert_eq!(got, [0, 1, 2, 4, 5, 6].map(Some).to_vec());
        assert_eq!(place(1, 8, "compact").unwrap(), (0..8).collect::<Vec<_>>());
    }

    #[test]
    fn scatter_placements() {
        assert_eq!(place(2, 2, "scatter").unwrap(), vec![0, 1, 4, 5]);
        assert_eq!(place(4, 1, "scatter").unwrap(), vec![0, 4, 1, 5]);
        assert_eq!(place(3, 2, "scatter").unwrap(), vec![0, 1, 4, 5, 2, 3]);
        assert_eq!(place(2, 4, "scatter").unwrap(), vec![0, 1, 2, 3, 4, 5, 6, 7]);
        // A process larger than its domain spills into the next one.
        assert_eq!(place(1, 6, "scatter").unwrap(), vec![0, 1, 2, 3, 4, 5]);
        // Four L3 domains in two packages: consecutive processes alternate packages.
        let mut topo = two_by_four();
        topo.l3_caches = vec![
            (8 << 20, vec![0, 1]),
            (8 << 20, vec![2, 3]),
            (8 << 20, vec![4, 5]),
            (8 << 20, vec![6, 7]),
        ];
        let allowed: Vec<usize> = (0..8).collect();
        let got = placement_with(&topo, 4, 1, &PinPolicy::Scatter, &allowed).unwrap();
        assert_eq!(got, vec![Some(0), Some(4), Some(2), Some(6)]);
    }

    #[test]
    fn oversubscription_wraps_and_is_reported() {
        let c = place(3, 3, "compact").unwrap();
        assert_eq!(c, vec![0, 1, 2, 3, 4, 5, 6, 7, 0]);
        let s = place(3, 3, "scatter").unwrap();
        assert_eq!(s, vec![0, 1, 2, 4, 5, 6, 3, 7, 0]);
        let s = place(2, 6, "scatter").unwrap();
        assert_eq!(s, vec![0, 1, 2, 3, 4, 5, 6, 7, 4, 5, 0, 1]);
        // One process with more threads than cores: every core once before any twice.
        let s = place(1, 10, "scatter").unwrap();
        assert_eq!(s, vec![0, 1, 2, 3, 4, 5, 6, 7, 0, 1]);
        let cores: Vec<Option<usize>> = c.into_iter().map(Some).collect();
        let text = describe_placement(3, 3, &cores);
        assert!(text.contains("oversubscribed"), "{text}");
        assert!(text.contains("core 0 hosts 2 workers"), "{text}");
        let text = describe_placement(2, 2, &[Some(0), Some(1), Some(2), None]);
        assert!(!text.contains("warning"), "{text}");
        assert!(text.lines().last().unwrap().trim_end().ends_with('-'), "{text}");
        assert_eq!(text.lines().count(), 5);
    }

    #[test]
    fn list_and_none_placements() {
        assert_eq!(place(2, 2, "7,6,1-2").unwrap(), vec![7, 6, 1, 2]);
        assert_eq!(place(1, 2, "3,5,9").unwrap(), vec![3, 5]);
        let e = place(2, 2, "0-2").unwrap_err();
        assert!(e.contains("need 4"), "{e}");
        let e = place(1, 2, "0,40").unwrap_err();
        assert!(e.contains("core 40"), "{e}");
        let none = placement_with(&two_by_four(), 2, 3, &PinPolicy::None, &[0]).unwrap();
        assert_eq!(none, vec![None; 6]);
        assert!(placement_with(&two_by_four(), 0, 3, &PinPolicy::Compact, &[0]).is_err());
        assert!(placement_with(&two_by_four(), usize::MAX, 3, &PinPolicy::Compact, &[0]).is_err());
    }

    #[test]
    fn restricted_allowed_set() {
        // Only cores 2, 3, 5 allowed (e.g. taskset): compact uses them in order and wraps.
        let allowed = [2, 3, 5];
        let got = placement_with(&two_by_four(), 2, 2, &PinPolicy::Compact, &allowed).unwrap();
        assert_eq!(got, vec![Some(2), Some(3), Some(5), Some(2)]);
        // Only SMT siblings allowed: they are used as they are.
        let got = placement_with(&two_by_four(), 1, 2, &PinPolicy::Compact, &[8, 9]).unwrap();
        assert_eq!(got, vec![Some(8), Some(9)]);
    }

    #[test]
    fn detects_this_machine() {
        let topo = Topology::detect();
        assert!(topo.cores >= 1 && topo.pus >= topo.cores, "{topo:?}");
        assert_eq!(topo.core_pus.len(), topo.cores);
        assert!(topo.packages >= 1 && topo.numa_nodes >= 1);
        let text = topo.describe();
        assert!(text.contains("cores:"), "{text}");
        let fallback = detect_fallback();
        assert!(
            fallback.cores >= 1 && fallback.core_pus.len() == fallback.cores,
            "{fallback:?}"
        );
        let allowed = allowed_cores();
        assert!(!allowed.is_empty());
        let p = placement(&topo, 1, 1, &PinPolicy::Compact).unwrap();
        assert!(allowed.contains(&p[0].unwrap()));
    }

    #[test]
    fn formats_lists_and_sizes() {
        assert_eq!(format_core_list(&[0, 1, 2, 3, 8, 10, 11]), "0-3,8,10-11");
        assert_eq!(format_core_list(&[]), "");
        assert_eq!(parse_size("512K"), Some(512 << 10));
        assert_eq!(parse_size("32M"), Some(32 << 20));
        assert_eq!(parse_size("x"), None);
        assert_eq!(format_bytes(32 << 20), "32 MiB");
    }
}
