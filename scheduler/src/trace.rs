//! Chrome trace (JSON) of task executions; opens in Perfetto (<https://ui.perfetto.dev>) and chrome://tracing.
//!
//! One track per worker thread (`pid` = virtual process, `tid` = worker index), one complete event
//! (`"ph": "X"`) per task execution named `"<part>:<block>"`, coloured by part through `"cname"`, with the
//! task's id, block, part, owner, executing process, CPU time and step in `args`. Metadata events name the
//! tracks (`"process p"`, `"worker w (core c)"`). Several runs can go into one trace, each shifted by an
//! offset so that consecutive steps lie end to end.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use serde::Serialize;
use serde_json::json;

use crate::graph::{TaskGraph, TaskRecord, TaskSpec};

/// The step of a task: `(run index, spec) -> step`.
type StepFn = Box<dyn Fn(usize, &TaskSpec) -> u64 + Send + Sync>;

/// One task execution, as kept until [`TraceWriter::write`].
#[derive(Clone, Copy, Debug)]
struct Event {
    task: u32,
    spec: TaskSpec,
    worker: u32,
    process: u32,
    start_ns: u64,
    dur_ns: u64,
    cpu_ns: u64,
    step: u64,
}

/// Spare palette for parts without a colour of their own, by part index.
const SPARE: [&str; 6] = [
    "generic_work",
    "cq_build_running",
    "rail_idle",
    "startup",
    "cq_build_attempt_passed",
    "grey",
];

/// Name and colour of one part (`TaskSpec::part`) in a trace.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct TracePart {
    /// Name of the part: the event name is `"<name>:<block>"` and the event category is the name.
    pub name: String,
    /// Chrome trace-viewer colour name (the event's `"cname"`, e.g. `"thread_state_running"`); `None`: a
    /// colour from a spare palette by part index.
    pub colour: Option<&'static str>,
}

impl TracePart {
    /// The colour written for this part when it is part number `part`.
    fn colour_at(&self, part: usize) -> &'static str {
        self.colour.unwrap_or(SPARE[part % SPARE.len()])
    }
}

/// Collects task records of one or more runs and writes them as a Chrome trace.
pub struct TraceWriter {
    parts: Vec<TracePart>,
    worker_cores: Vec<Option<usize>>,
    threads_per_process: usize,
    step_of: StepFn,
    runs: usize,
    events: Vec<Event>,
    /// Process of every worker seen (from the layout and from the records).
    workers: BTreeMap<u32, u32>,
    end_ns: u64,
}

impl std::fmt::Debug for TraceWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TraceWriter")
            .field("parts", &self.parts)
            .field("worker_cores", &self.worker_cores)
            .field("threads_per_process", &self.threads_per_process)
            .field("runs", &self.runs)
            .field("events", &self.events.len())
            .finish()
    }
}

impl TraceWriter {
    /// A writer for workers laid out process-major (`worker = p * threads_per_process + t`), pinned to
    /// `worker_cores` (`None`: unpinned). `parts[i]` names and colours `TaskSpec::part == i`; a part without
    /// an entry is named `"part<i>"` and coloured from the spare palette. The step recorded for a task is
    /// the index of its run unless [`TraceWriter::with_step`] sets another rule.
    pub fn new(parts: Vec<TracePart>, worker_cores: Vec<Option<usize>>, threads_per_process: usize) -> Self {
        let t = threads_per_process.max(1);
        let workers = (0..worker_cores.len()).map(|w| (w as u32, (w / t) as u32)).collect();
        TraceWriter {
            parts,
            worker_cores,
            threads_per_process: t,
            step_of: Box::new(|run, _| run as u64),
            runs: 0,
            events: Vec::new(),
            workers,
            end_ns: 0,
        }
    }

    /// Sets the rule for the `step` argument: `f(run index, spec)`, e.g. decoding a step offset from
    /// `spec.payload` when one graph spans several steps.
    pub fn with_step(mut self, f: impl Fn(usize, &TaskSpec) -> u64 + Send + Sync + 'static) -> Self {
        self.step_of = Box::new(f);
        self
    }

    /// Adds one run of `graph`: `records[t]` is task `t`'s record (times relative to the run's start), and
    /// every time is shifted by `offset_ns`. Extra records or tasks without a record are ignored.
    pub fn add_run(&mut self, graph: &TaskGraph, records: &[TaskRecord], offset_ns: u64) {
        let run = self.runs;
        self.runs += 1;
        self.events.reserve(graph.len().min(records.len()));
        for (task, (spec, rec)) in graph.specs().iter().zip(records).enumerate() {
            let start_ns = offset_ns.saturating_add(rec.start_ns);
            let dur_ns = rec.end_ns.saturating_sub(rec.start_ns);
            self.end_ns = self.end_ns.max(start_ns.saturating_add(dur_ns));
            self.workers.entry(rec.worker).or_insert(rec.process);
            self.events.push(Event {
                task: task as u32,
                spec: *spec,
                worker: rec.worker,
                process: rec.process,
                start_ns,
                dur_ns,
                cpu_ns: rec.cpu_ns,
                step: (self.step_of)(run, spec),
            });
        }
    }

    /// Number of task events collected so far.
    pub fn event_count(&self) -> usize {
        self.events.len()
    }

    /// Latest end of any event so far, in ns on the trace's time axis: the offset for a following run.
    pub fn end_ns(&self) -> u64 {
        self.end_ns
    }

    /// Writes the trace to `path` (through a temporary file in the same folder and a rename, so a failed
    /// write leaves no half-written trace).
    ///
    /// # Errors
    /// Any I/O error creating, writing or renaming the file (or a `path` without a file name).
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        let name = path.file_name().ok_or_else(|| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("trace path {} has no file name", path.display()),
            )
        })?;
        let tmp = path.with_file_name(format!(".{}.tmp-{}", name.to_string_lossy(), std::process::id()));
        let result = std::fs::File::create(&tmp).and_then(|f| {
            let mut out = std::io::BufWriter::new(f);
            self.write_to(&mut out)?;
            out.flush()?;
            out.into_inner().map_err(|e| e.into_error())?.sync_all()
        });
        match result.and_then(|()| std::fs::rename(&tmp, path)) {
            Ok(()) => Ok(()),
            Err(e) => {
                let _ = std::fs::remove_file(&tmp);
                Err(e)
            }
        }
    }

    /// Writes the JSON document to `out`.
    fn write_to(&self, out: &mut impl Write) -> std::io::Result<()> {
        out.write_all(b"{\"displayTimeUnit\":\"ms\",\"otherData\":{\"producer\":\"blockflow-scheduler\"},")?;
        out.write_all(b"\"traceEvents\":[\n")?;
        let mut first = true;
        let mut emit = |out: &mut dyn Write, value: &dyn erased::Ser| -> std::io::Result<()> {
            if !first {
                out.write_all(b",\n")?;
            }
            first = false;
            value.ser(out)
        };
        let mut processes: Vec<u32> = self.workers.values().copied().collect();
        processes.sort_unstable();
        processes.dedup();
        for &p in &processes {
            emit(
                out,
                &json!({"name": "process_name", "ph": "M", "pid": p, "tid": 0,
                "args": {"name": format!("process {p}")}}),
            )?;
            emit(
                out,
                &json!({"name": "process_sort_index", "ph": "M", "pid": p, "tid": 0,
                "args": {"sort_index": p}}),
            )?;
        }
        for (&w, &p) in &self.workers {
            let label = match self.worker_cores.get(w as usize) {
                Some(Some(c)) => format!("worker {w} (core {c})"),
                Some(None) => format!("worker {w} (unpinned)"),
                None => format!("worker {w}"),
            };
            emit(
                out,
                &json!({"name": "thread_name", "ph": "M", "pid": p, "tid": w, "args": {"name": label}}),
            )?;
            emit(
                out,
                &json!({"name": "thread_sort_index", "ph": "M", "pid": p, "tid": w,
                "args": {"sort_index": w}}),
            )?;
        }
        let fallback: Vec<String> = (0..=u8::MAX).map(|i| format!("part{i}")).collect();
        for e in &self.events {
            let index = e.spec.part as usize;
            let (part, cname) = match self.parts.get(index) {
                Some(p) => (p.name.as_str(), p.colour_at(index)),
                None => (fallback[index].as_str(), SPARE[index % SPARE.len()]),
            };
            let event = Complete {
                name: format!("{part}:{}", e.spec.block),
                cat: part,
                ph: "X",
                ts: e.start_ns as f64 / 1000.0,
                dur: e.dur_ns as f64 / 1000.0,
                pid: e.process,
                tid: e.worker,
                cname,
                args: Args {
                    task: e.task,
                    block: e.spec.block,
                    part,
                    owner: e.spec.owner,
                    process: e.process,
                    cpu_us: e.cpu_ns as f64 / 1000.0,
                    step: e.step,
                },
            };
            emit(out, &event)?;
        }
        out.write_all(b"\n]}\n")
    }
}

/// Serialising values of different types through one closure.
mod erased {
    /// A value that writes itself as JSON.
    pub trait Ser {
        fn ser(&self, out: &mut dyn std::io::Write) -> std::io::Result<()>;
    }
    impl<T: serde::Serialize> Ser for T {
        fn ser(&self, out: &mut dyn std::io::Write) -> std::io::Result<()> {
            serde_json::to_writer(out, self).map_err(std::io::Error::other)
        }
    }
}

/// A complete ("X") event.
#[derive(Serialize)]
struct Complete<'a> {
    name: String,
    cat: &'a str,
    ph: &'static str,
    ts: f64,
    dur: f64,
    pid: u32,
    tid: u32,
    cname: &'static str,
    args: Args<'a>,
}

/// The `args` of a task event.
#[derive(Serialize)]
struct Args<'a> {
    task: u32,
    block: u32,
    part: &'a str,
    owner: u32,
    process: u32,
    cpu_us: f64,
    step: u64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::GraphBuilder;

    fn part(name: &str, colour: Option<&'static str>) -> TracePart {
        TracePart {
            name: name.into(),
            colour,
        }
    }

    fn small() -> (TaskGraph, Vec<TaskRecord>) {
        let mut g = GraphBuilder::new();
        let spec = |owner, part, block| TaskSpec {
            owner,
            part,
            block,
            payload: 0,
        };
        let a = g.add(spec(0, 0, 3));
        let b = g.add(spec(1, 1, 4));
        let c = g.add(spec(1, 7, 5));
        g.edge(a, b);
        g.edge(a, c);
        let rec = |worker, process, start_ns, end_ns, cpu_ns| TaskRecord {
            worker,
            process,
            start_ns,
            end_ns,
            cpu_ns,
        };
        let records = vec![
            rec(0, 0, 1000, 3500, 2000),
            rec(2, 1, 4000, 9000, 4500),
            rec(1, 0, 3600, 4100, 400),
        ];
        (g.build().unwrap(), records)
    }

    #[test]
    fn writes_a_trace_that_parses_back() {
        let (g, records) = small();
        let cores = vec![Some(0), Some(1), None, Some(1)];
        let parts = vec![
            part("collide", Some("thread_state_running")),
            part("stream", Some("rail_response")),
        ];
        let mut w = TraceWriter::new(parts, cores, 2).with_step(|run, spec| 10 * run as u64 + spec.payload as u64);
        w.add_run(&g, &records, 0);
        assert_eq!(w.end_ns(), 9000);
        w.add_run(&g, &records, w.end_ns());
        assert_eq!(w.event_count(), 6);
        assert_eq!(w.end_ns(), 18000);

        let dir = std::env::temp_dir().join(format!("blockflow-trace-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("trace.json");
        w.write(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
        let events = doc["traceEvents"].as_array().unwrap();
        let complete: Vec<&serde_json::Value> = events.iter().filter(|e| e["ph"] == "X").collect();
        let meta: Vec<&serde_json::Value> = events.iter().filter(|e| e["ph"] == "M").collect();
        assert_eq!(complete.len(), 6);
        // 2 processes x (name + sort index) + 4 workers x (name + sort index).
        assert_eq!(meta.len(), 12);
        let names: Vec<&str> = complete.iter().map(|e| e["name"].as_str().unwrap()).collect();
        assert_eq!(
            names,
            ["collide:3", "stream:4", "part7:5", "collide:3", "stream:4", "part7:5"]
        );
        for (i, e) in complete.iter().enumerate() {
            let r = &records[i % 3];
            let offset = if i < 3 { 0 } else { 9000 };
            assert_eq!(e["ts"].as_f64().unwrap(), (offset + r.start_ns) as f64 / 1000.0);
            assert_eq!(e["dur"].as_f64().unwrap(), (r.end_ns - r.start_ns) as f64 / 1000.0);
            assert_eq!(e["pid"], r.process);
            assert_eq!(e["tid"], r.worker);
            assert_eq!(e["args"]["task"], i % 3);
            assert_eq!(e["args"]["cpu_us"].as_f64().unwrap(), r.cpu_ns as f64 / 1000.0);
            assert_eq!(e["args"]["step"], if i < 3 { 0 } else { 10 });
            assert_eq!(e["args"]["owner"], g.spec((i % 3) as u32).owner);
            assert_eq!(e["args"]["process"], r.process);
        }
        assert_eq!(complete[0]["cname"], "thread_state_running");
        assert_eq!(complete[1]["cname"], "rail_response");
        // Part 7 has no entry: spare palette by index (7 % 6).
        assert_eq!(complete[2]["cname"], "cq_build_running");
        assert_eq!(complete[1]["args"]["part"], "stream");
        assert_eq!(complete[2]["args"]["block"], 5);
        let thread_names: Vec<&str> = meta
            .iter()
            .filter(|e| e["name"] == "thread_name")
            .map(|e| e["args"]["name"].as_str().unwrap())
            .collect();
        assert_eq!(
            thread_names,
            [
                "worker 0 (core 0)",
                "worker 1 (core 1)",
                "worker 2 (unpinned)",
                "worker 3 (core 1)"
            ]
        );
        assert!(meta
            .iter()
            .any(|e| e["name"] == "process_name" && e["args"]["name"] == "process 1"));
        // No temporary file is left behind.
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left.len(), 1, "{left:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The JSON document a writer produces for `small()` run once.
    fn document(parts: Vec<TracePart>) -> String {
        let (g, records) = small();
        let mut w = TraceWriter::new(parts, vec![Some(0), Some(1), None], 2);
        w.add_run(&g, &records, 0);
        let mut out = Vec::new();
        w.write_to(&mut out).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn explicit_colours_and_palette_fallback() {
        let text = document(vec![part("lbm", Some("thread_state_running")), part("extra", None)]);
        let doc: serde_json::Value = serde_json::from_str(&text).unwrap();
        let cnames: Vec<(&str, &str)> = doc["traceEvents"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| e["ph"] == "X")
            .map(|e| (e["name"].as_str().unwrap(), e["cname"].as_str().unwrap()))
            .collect();
        // Part 0 keeps its explicit colour, part 1 (no colour) and part 7 (no entry) take the palette by index.
        assert_eq!(
            cnames,
            [
                ("lbm:3", "thread_state_running"),
                ("extra:4", "cq_build_running"),
                ("part7:5", "cq_build_running")
            ]
        );
        // Without any colour every part takes the palette entry of its index, whatever its name.
        let text = document(vec![part("lbm", None), part("stream", None)]);
        assert!(text.contains(r#""name":"lbm:3","cat":"lbm","ph":"X""#), "{text}");
        assert!(text.contains(r#""cname":"generic_work""#), "{text}");
        assert!(!text.contains("thread_state_running"), "{text}");
        // An explicit colour equal to the palette entry writes the same document as `None`.
        assert_eq!(
            document(vec![part("a", Some("generic_work")), part("b", None)]),
            document(vec![part("a", None), part("b", Some("cq_build_running"))])
        );
    }

    #[test]
    fn failed_write_leaves_nothing() {
        let (g, records) = small();
        let mut w = TraceWriter::new(vec![], vec![], 1);
        w.add_run(&g, &records[..2], 0);
        assert_eq!(w.event_count(), 2);
        let missing = std::env::temp_dir()
            .join("blockflow-no-such-dir-for-trace")
            .join("t.json");
        assert!(w.write(&missing).is_err());
        assert!(w.write(Path::new("/")).is_err());
    }
}
