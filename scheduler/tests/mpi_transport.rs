//! The MPI transport on 3 ranks of a real MPI job (a build with `--features mpi`, Open MPI): messages of
//! every size arrive whole and in order per sender and tag, from any sender by class, and the collectives
//! combine every rank in rank order. The test starts `mpirun`, which runs this same test binary once per
//! rank; in a rank (the launcher's environment set) the test body is the rank's part.
#![cfg(feature = "mpi")]

use blockflow_scheduler::transport::{FloatOp, IntOp, Mpi, Tag, Transport};
use std::process::Command;

fn message(from: usize, to: usize, tag: Tag, k: usize) -> Vec<u8> {
    let len = [0, 1, 7, 4096, 100_000, 3_000_000][(from + 3 * to + tag.value as usize + k) % 6];
    (0..len)
        .map(|i| (i as u64 ^ (from as u64 * 31 + to as u64 * 7 + tag.value as u64 * 13 + k as u64)) as u8)
        .collect()
}

fn rank() {
    let t = Mpi::init().expect("MPI starts");
    assert_eq!(t.ranks(), 3);
    assert!(t.tag_ub() >= 32767);
    let (local, on_node) = t.node_rank();
    assert!(local < on_node && on_node <= 3);
    let tags = [Tag::new(0, 0), Tag::new(0, 5), Tag::new(3, 40000.min(t.tag_ub()))];
    for to in 0..3 {
        for tag in tags {
            for k in 0..3 {
                t.send(to, tag, message(t.rank(), to, tag, k)).unwrap();
            }
        }
    }
    // Class 3 by sender and tag, newest sender first; class 0 from any sender.
    for from in (0..3).rev() {
        for k in 0..3 {
            assert_eq!(t.recv(from, tags[2]).unwrap(), message(from, t.rank(), tags[2], k));
        }
    }
    let mut next = std::collections::HashMap::new();
    let mut got = 0;
    while got < 3 * 2 * 3 {
        t.poll().unwrap();
        let Some((from, tag, bytes)) = t.try_recv_any(0).unwrap() else {
            continue;
        };
        let k = next.entry((from, tag)).or_insert(0);
        assert_eq!(bytes, message(from, t.rank(), tag, *k));
        *k += 1;
        got += 1;
    }
    assert_eq!(t.try_recv_any(0).unwrap(), None);
    let r = t.rank() as u64;
    let mut v = [r + 1, 10 * r, 1 << r];
    t.allreduce_u64(&mut v, IntOp::Sum).unwrap();
    assert_eq!(v, [6, 30, 7]);
    let mut v = [r + 1, 10 * r];
    t.allreduce_u64(&mut v, IntOp::Max).unwrap();
    assert_eq!(v, [3, 20]);
    let mut f = [r as f64 * 0.5, if r == 1 { f64::NAN } else { 1.0 }];
    t.allreduce_f64(&mut f, FloatOp::Max).unwrap();
    assert_eq!(f[0], 1.0);
    assert!(f[1].is_nan());
    let all = t.allgather(&vec![r as u8; 1000 * t.rank()]).unwrap();
    assert_eq!(all.iter().map(|b| b.len()).collect::<Vec<_>>(), vec![0, 1000, 2000]);
    let mut b = if t.rank() == 2 {
        b"from two".to_vec()
    } else {
        Vec::new()
    };
    t.broadcast(2, &mut b).unwrap();
    assert_eq!(b, b"from two");
    t.finish(std::time::Duration::from_secs(10));
}

#[test]
fn the_mpi_transport_on_three_ranks() {
    if std::env::var_os("OMPI_COMM_WORLD_SIZE").is_some() {
        rank();
        return;
    }
    let exe = std::env::current_exe().unwrap();
    let o = Command::new("mpirun")
        .args(blockflow_scheduler::transport::MPIRUN_SMALL_MACHINE)
        .args(["-np", "3"])
        .arg(exe)
        .args(["--exact", "the_mpi_transport_on_three_ranks", "--test-threads=1"])
        .output()
        .expect("mpirun runs");
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}
