//! The task graph: tasks with an owner process, a part label and a block, and the edges between them.
//! Compiled once per block layout into successor lists and in-degrees (compressed rows); the executor
//! re-arms it for every run by resetting atomic counters (Taskflow's "compile once, run many").

/// Index of a task in its graph.
pub type TaskId = u32;

/// What a task is, for scheduling and for its timing record. The scheduler never interprets `part`,
/// `block` or `payload`; they are labels the caller chooses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TaskSpec {
    /// Virtual process that owns the task: it becomes ready in this process's queues.
    pub owner: u32,
    /// Part label (e.g. an index into the caller's list of part names: lbm, boundary, exchange, ...).
    pub part: u8,
    /// Block the task works on (for records and traces).
    pub block: u32,
    /// Free payload for the caller (e.g. step offset and neighbour slot).
    pub payload: u32,
}

impl TaskSpec {
    /// A task owned by `owner` with part, block and payload 0 (tests and synthetic graphs).
    pub fn for_owner(owner: u32) -> Self {
        TaskSpec {
            owner,
            part: 0,
            block: 0,
            payload: 0,
        }
    }
}

/// Builder: add tasks, then edges `before → after` (and external dependencies), then
/// [`GraphBuilder::build`].
#[derive(Clone, Debug, Default)]
pub struct GraphBuilder {
    specs: Vec<TaskSpec>,
    edges: Vec<(TaskId, TaskId)>,
    external: Vec<u32>,
}

impl GraphBuilder {
    /// An empty builder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a task and returns its id (ids are dense, in insertion order).
    pub fn add(&mut self, spec: TaskSpec) -> TaskId {
        self.specs.push(spec);
        self.external.push(0);
        (self.specs.len() - 1) as TaskId
    }

    /// Adds `n` dependencies of `task` on something outside the graph (a message from another rank):
    /// the task becomes ready only when its predecessors have finished *and* the driver has released it
    /// `n` times ([`crate::executor::Executor::run_with_progress`]).
    pub fn external(&mut self, task: TaskId, n: u32) {
        self.external[task as usize] += n;
    }

    /// Adds the dependency `before → after` (duplicates are removed at build time).
    pub fn edge(&mut self, before: TaskId, after: TaskId) {
        self.edges.push((before, after));
    }

    /// Number of tasks so far.
    pub fn len(&self) -> usize {
        self.specs.len()
    }

    /// Whether no task was added.
    pub fn is_empty(&self) -> bool {
        self.specs.is_empty()
    }

    /// Compiles the graph: successor lists in compressed rows, in-degrees, roots. Fails on an edge to an
    /// unknown task, a self-loop or a cycle (naming a task on it).
    pub fn build(mut self) -> Result<TaskGraph, String> {
        let n = self.specs.len();
        for &(a, b) in &self.edges {
            if a as usize >= n || b as usize >= n {
                return Err(format!("edge {a} -> {b} names a task that does not exist ({n} tasks)"));
            }
            if a == b {
                return Err(format!("task {a} depends on itself"));
            }
        }
        self.edges.sort_unstable();
        self.edges.dedup();
        let mut offsets = vec![0u32; n + 1];
        for &(a, _) in &self.edges {
            offsets[a as usize + 1] += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        let succ: Vec<TaskId> = self.edges.iter().map(|&(_, b)| b).collect();
        let mut indegree = vec![0u32; n];
        for &(_, b) in &self.edges {
            indegree[b as usize] += 1;
        }
        // Kahn's algorithm: every task must be reachable in topological order.
        let mut deg = indegree.clone();
        let mut stack: Vec<TaskId> = (0..n as TaskId).filter(|&t| deg[t as usize] == 0).collect();
        let roots: Vec<TaskId> = stack
            .iter()
            .copied()
            .filter(|&t| self.external[t as usize] == 0)
            .collect();
        let mut seen = 0;
        while let Some(t) = stack.pop() {
            seen += 1;
            for &s in &succ[offsets[t as usize] as usize..offsets[t as usize + 1] as usize] {
                deg[s as usize] -= 1;
                if deg[s as usize] == 0 {
                    stack.push(s);
                }
            }
        }
        if seen != n {
            let t = deg.iter().position(|&d| d > 0).unwrap_or(0);
            return Err(format!(
                "the task graph has a cycle through task {t} ({:?})",
                self.specs[t]
            ));
        }
        let processes = self.specs.iter().map(|s| s.owner + 1).max().unwrap_or(0) as usize;
        for (d, e) in indegree.iter_mut().zip(&self.external) {
            *d += e;
        }
        let external_total = self.external.iter().map(|&e| e as u64).sum();
        Ok(TaskGraph {
            specs: self.specs,
            offsets,
            succ,
            indegree,
            roots,
            processes,
            external: self.external,
            external_total,
        })
    }
}

/// A compiled, immutable task graph.
#[derive(Clone, Debug)]
pub struct TaskGraph {
    specs: Vec<TaskSpec>,
    offsets: Vec<u32>,
    succ: Vec<TaskId>,
    indegree: Vec<u32>,
    roots: Vec<TaskId>,
    processes: usize,
    external: Vec<u32>,
    external_total: u64,
}

impl TaskGraph {
    /// Number of tasks.
    pub fn len(&self) -> usize {
        self.specs.len()
    }

    /// Whether the graph has no task.
    pub fn is_empty(&self) -> bool {
        self.specs.is_empty()
    }

    /// The task's spec.
    pub fn spec(&self, t: TaskId) -> &TaskSpec {
        &self.specs[t as usize]
    }

    /// All specs in id order.
    pub fn specs(&self) -> &[TaskSpec] {
        &self.specs
    }

    /// Successors of a task.
    pub fn successors(&self, t: TaskId) -> &[TaskId] {
        &self.succ[self.offsets[t as usize] as usize..self.offsets[t as usize + 1] as usize]
    }

    /// Number of predecessors of each task, external dependencies included.
    pub fn indegrees(&self) -> &[u32] {
        &self.indegree
    }

    /// Tasks without predecessors (in the graph or outside it).
    pub fn roots(&self) -> &[TaskId] {
        &self.roots
    }

    /// External dependencies of each task ([`GraphBuilder::external`]).
    pub fn external(&self) -> &[u32] {
        &self.external
    }

    /// External dependencies of all tasks together: the releases a run of the graph waits for.
    pub fn external_total(&self) -> u64 {
        self.external_total
    }

    /// One more than the largest owner (the process count the graph needs at least).
    pub fn processes(&self) -> usize {
        self.processes
    }

    /// Number of edges.
    pub fn edge_count(&self) -> usize {
        self.succ.len()
    }

    /// A synthetic step of 4×4×4 periodic blocks with 6 parts each (lbm → boundary → pack; the packs of the
    /// six face neighbours and the own pack → unpack → map → rigid body), blocks split into contiguous
    /// ranges over `processes`: the stencil shape of the fluid step, for the executor's stress test and
    /// overhead bench. Returns the graph and its edges.
    pub fn synthetic_stencil(processes: u32) -> (TaskGraph, Vec<(TaskId, TaskId)>) {
        const N: u32 = 4;
        let blocks = N * N * N;
        let id = |b: u32, part: u32| b * 6 + part;
        let mut g = GraphBuilder::new();
        for b in 0..blocks {
            for part in 0..6 {
                g.add(TaskSpec {
                    owner: b * processes / blocks,
                    part: part as u8,
                    block: b,
                    payload: 0,
                });
            }
        }
        let mut edges = Vec::new();
        for b in 0..blocks {
            let (x, y, z) = (b % N, (b / N) % N, b / (N * N));
            edges.extend([(id(b, 0), id(b, 1)), (id(b, 1), id(b, 2)), (id(b, 2), id(b, 3))]);
            for (dx, dy, dz) in [
                (1, 0, 0),
                (N - 1, 0, 0),
                (0, 1, 0),
                (0, N - 1, 0),
                (0, 0, 1),
                (0, 0, N - 1),
            ] {
                let nb = (x + dx) % N + ((y + dy) % N) * N + ((z + dz) % N) * N * N;
                edges.push((id(nb, 2), id(b, 3)));
            }
            edges.extend([(id(b, 3), id(b, 4)), (id(b, 4), id(b, 5))]);
        }
        for &(a, b) in &edges {
            g.edge(a, b);
        }
        (g.build().expect("the stencil graph is acyclic"), edges)
    }

    /// A graph of tasks with the given owners (task i owned by `owners[i]`, part, block and payload 0) and
    /// edges: synthetic graphs for tests and benchmarks.
    pub fn from_edges(owners: &[u32], edges: &[(TaskId, TaskId)]) -> Result<TaskGraph, String> {
        let mut g = GraphBuilder::new();
        for &o in owners {
            g.add(TaskSpec::for_owner(o));
        }
        for &(a, b) in edges {
            g.edge(a, b);
        }
        g.build()
    }
}

/// What one execution of one task recorded (the paper's per-part timings come from these).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TaskRecord {
    /// Worker thread index (0 .. P*T, process-major).
    pub worker: u32,
    /// Process of that worker (may differ from the owner when stealing is global).
    pub process: u32,
    /// Wall-clock start, nanoseconds since the run began.
    pub start_ns: u64,
    /// Wall-clock end, nanoseconds since the run began.
    pub end_ns: u64,
    /// Thread CPU time spent in the task (CLOCK_THREAD_CPUTIME_ID), nanoseconds: the CPU time of the
    /// worker's batch shared by wall duration (see the executor's timing notes).
    pub cpu_ns: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(owner: u32) -> TaskSpec {
        TaskSpec::for_owner(owner)
    }

    #[test]
    fn builds_csr_and_rejects_cycles() {
        let mut g = GraphBuilder::new();
        let a = g.add(spec(0));
        let b = g.add(spec(1));
        let c = g.add(spec(0));
        g.edge(a, b);
        g.edge(a, c);
        g.edge(a, c);
        g.edge(b, c);
        let t = g.build().unwrap();
        assert_eq!(t.successors(a), &[b, c]);
        assert_eq!(t.indegrees(), &[0, 1, 2]);
        assert_eq!(t.roots(), &[a]);
        assert_eq!(t.processes(), 2);
        assert_eq!(t.external_total(), 0);
        // An external dependency counts in the in-degree and keeps a task out of the roots.
        let mut g = GraphBuilder::new();
        let a = g.add(spec(0));
        let b = g.add(spec(0));
        let c = g.add(spec(0));
        g.edge(a, b);
        g.external(a, 1);
        g.external(c, 2);
        let t = g.build().unwrap();
        assert_eq!(t.indegrees(), &[1, 1, 2]);
        assert!(t.roots().is_empty());
        assert_eq!((t.external(), t.external_total()), (&[1, 0, 2][..], 3));
        let mut g = GraphBuilder::new();
        let a = g.add(spec(0));
        let b = g.add(spec(0));
        g.edge(a, b);
        g.edge(b, a);
        assert!(g.build().unwrap_err().contains("cycle"));
    }
}
