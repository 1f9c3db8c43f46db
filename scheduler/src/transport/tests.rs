//! Conformance of the transports: messages in any order, of any size, with delays; collectives; abort.

use super::*;
use std::time::Duration;

/// The bytes of the k-th message from `from` to `to` under `tag`: a size that varies from empty to
/// 100 kB, and contents that identify the message.
fn message(from: Rank, to: Rank, tag: Tag, k: usize) -> Vec<u8> {
    let len = [0, 1, 7, 4096, 100_000][(from + 3 * to + tag.value as usize + k) % 5];
    (0..len)
        .map(|i| (i as u64 ^ (from as u64 * 31 + to as u64 * 7 + tag.value as u64 * 13 + k as u64 * 101)) as u8)
        .collect()
}

const TAGS: [Tag; 3] = [Tag::new(0, 0), Tag::new(0, 5), Tag::new(3, 0)];
const PER_TAG: usize = 4;

/// Every rank sends PER_TAG messages under each tag to every rank (itself included), then receives
/// them from the last sender and tag to the first; each (sender, tag) must come in send order.
fn all_to_all(t: &dyn Transport) {
    let r = t.ranks();
    for to in 0..r {
        for tag in TAGS {
            for k in 0..PER_TAG {
                t.send(to, tag, message(t.rank(), to, tag, k)).expect("send");
            }
        }
    }
    for from in (0..r).rev() {
        for tag in TAGS.iter().rev() {
            for k in 0..PER_TAG {
                let m = t.recv(from, *tag).expect("recv");
                assert_eq!(
                    m,
                    message(from, t.rank(), *tag, k),
                    "rank {} from {from} {tag:?} #{k}",
                    t.rank()
                );
            }
        }
    }
    for from in 0..r {
        for tag in TAGS {
            assert_eq!(t.try_recv(from, tag).expect("try_recv"), None, "no extra message");
        }
    }
}

#[test]
fn messages_arrive_whole_and_in_order_per_sender_and_tag() {
    for ranks in [1, 2, 3, 5] {
        run_loopback(ranks, None, |t| all_to_all(t));
    }
    all_to_all(&SingleRank::new());
}

#[test]
fn seeded_delays_keep_the_order_per_sender_and_tag() {
    for seed in 1..4 {
        let delays = Some(Delays {
            seed,
            max: Duration::from_micros(500),
        });
        run_loopback(4, delays, |t| all_to_all(t));
        // Many messages under one tag: later ones may draw shorter delays and must still come later.
        run_loopback(2, delays, |t| {
            let other = 1 - t.rank();
            for k in 0..200 {
                t.send(other, Tag::new(1, 9), vec![k as u8, (k >> 8) as u8])
                    .expect("send");
            }
            for k in 0..200 {
                assert_eq!(
                    t.recv(other, Tag::new(1, 9)).expect("recv"),
                    vec![k as u8, (k >> 8) as u8]
                );
            }
        });
    }
}

#[test]
fn delays_are_a_function_of_the_seed() {
    let d = |seed| Delays {
        seed,
        max: Duration::from_millis(1),
    };
    let a = Loopback::group(2, Some(d(7)));
    let b = Loopback::group(2, Some(d(7)));
    let c = Loopback::group(2, Some(d(8)));
    let seq = |g: &[Loopback], s| (0..64).map(|n| g[1].delay(&d(s), n)).collect::<Vec<_>>();
    assert_eq!(seq(&a, 7), seq(&b, 7));
    assert_ne!(seq(&a, 7), seq(&c, 8));
    assert!(seq(&a, 7).iter().all(|x| *x <= Duration::from_millis(1)));
}

#[test]
fn a_message_with_a_delay_arrives_only_after_it() {
    let g = Loopback::group(
        2,
        Some(Delays {
            seed: 3,
            max: Duration::from_millis(20),
        }),
    );
    let start = std::time::Instant::now();
    g[0].send(1, Tag::new(0, 1), vec![42]).expect("send");
    let expected = g[0].delay(
        &Delays {
            seed: 3,
            max: Duration::from_millis(20),
        },
        0,
    );
    assert_eq!(g[1].recv(0, Tag::new(0, 1)).expect("recv"), vec![42]);
    assert!(start.elapsed() >= expected, "received before its delay");
}

#[test]
fn integer_reductions_combine_every_rank() {
    let out = run_loopback(5, None, |t| {
        let r = t.rank() as u64;
        let mut v = [r + 1, r * 10, 1 << r];
        let mut sum = v;
        t.allreduce_u64(&mut sum, IntOp::Sum).expect("sum");
        let mut max = v;
        t.allreduce_u64(&mut max, IntOp::Max).expect("max");
        let mut min = v;
        t.allreduce_u64(&mut min, IntOp::Min).expect("min");
        t.allreduce_u64(&mut v, IntOp::Or).expect("or");
        (sum, max, min, v)
    });
    for o in &out {
        assert_eq!(o.0, [15, 100, 31]);
        assert_eq!(o.1, [5, 40, 16]);
        assert_eq!(o.2, [1, 0, 1]);
        let or = |v: &[u64]| v.iter().fold(0, |a, b| a | b);
        assert_eq!(o.3, [or(&[1, 2, 3, 4, 5]), or(&[0, 10, 20, 30, 40]), 31]);
    }
}

#[test]
fn float_extremes_propagate_nan_and_are_the_same_bits_everywhere() {
    let out = run_loopback(3, None, |t| {
        let r = t.rank() as f64;
        let nan_on_1 = if t.rank() == 1 { f64::NAN } else { r };
        let zero = if t.rank() == 0 { 0.0 } else { -0.0 };
        let mut max = [r, -r, nan_on_1, zero];
        t.allreduce_f64(&mut max, FloatOp::Max).expect("max");
        let mut min = [r, -r, nan_on_1, zero];
        t.allreduce_f64(&mut min, FloatOp::Min).expect("min");
        (max.map(f64::to_bits), min.map(f64::to_bits))
    });
    for o in &out {
        assert_eq!(o, &out[0], "every rank holds the same bits");
    }
    let (max, min) = (out[0].0.map(f64::from_bits), out[0].1.map(f64::from_bits));
    assert_eq!((max[0], max[1], min[0], min[1]), (2.0, 0.0, 0.0, -2.0));
    assert!(
        max[2].is_nan() && min[2].is_nan(),
        "a NaN on one rank reaches every rank"
    );
    // +0 and -0 compare equal: the first rank's value stays.
    assert_eq!(max[3].to_bits(), 0.0f64.to_bits());
}

#[test]
fn allgather_and_broadcast_carry_bytes_of_any_size() {
    run_loopback(4, None, |t| {
        let mine: Vec<u8> = (0..t.rank() * 1000).map(|i| (i + t.rank()) as u8).collect();
        let all = t.allgather(&mine).expect("allgather");
        for (r, b) in all.iter().enumerate() {
            assert_eq!(b.len(), r * 1000);
            assert!(b.iter().enumerate().all(|(i, &x)| x == (i + r) as u8));
        }
        for root in 0..t.ranks() {
            let mut b = if t.rank() == root {
                vec![root as u8; 10 + root]
            } else {
                vec![99]
            };
            t.broadcast(root, &mut b).expect("broadcast");
            assert_eq!(b, vec![root as u8; 10 + root]);
        }
    });
    let s = SingleRank::new();
    assert_eq!(s.allgather(&[1, 2]).expect("allgather"), vec![vec![1, 2]]);
    let mut v = [3u64];
    s.allreduce_u64(&mut v, IntOp::Sum).expect("sum");
    assert_eq!(v, [3]);
}

#[test]
fn an_abort_releases_ranks_waiting_in_collectives_and_receives() {
    let out = run_loopback(3, None, |t| match t.rank() {
        1 => {
            t.abort(2, "bad key scene.kind");
            Err(t.poll().expect_err("aborted"))
        }
        0 => t.allgather(&[0]).map(|_| ()),
        _ => t.recv(1, Tag::new(0, 0)).map(|_| ()),
    });
    let expected = TransportError::Aborted {
        rank: 1,
        code: 2,
        message: "bad key scene.kind".into(),
    };
    for o in out {
        assert_eq!(o, Err(expected.clone()));
    }
    assert_eq!(expected.to_string(), "rank 1 aborted (exit code 2): bad key scene.kind");
}

#[test]
fn a_panicking_rank_does_not_leave_the_others_waiting() {
    let r = std::panic::catch_unwind(|| {
        run_loopback(3, None, |t| {
            if t.rank() == 2 {
                panic!("rank driver failed");
            }
            t.allgather(&[1]).map(|_| ())
        })
    });
    assert!(r.is_err(), "the panic comes back to the caller");
}

#[test]
fn different_collectives_at_the_same_point_are_an_error() {
    let out = run_loopback(2, None, |t| {
        if t.rank() == 0 {
            t.allgather(&[1]).map(|_| ())
        } else {
            let mut b = vec![1];
            t.broadcast(0, &mut b)
        }
    });
    for o in out {
        assert!(matches!(o, Err(TransportError::Mismatch(_))), "{o:?}");
    }
}

#[test]
fn ranks_outside_the_group_are_refused() {
    let g = Loopback::group(2, None);
    assert_eq!(
        g[0].send(2, Tag::new(0, 0), vec![]),
        Err(TransportError::NoSuchRank { rank: 2, ranks: 2 })
    );
    let s = SingleRank::new();
    assert_eq!(
        s.try_recv(1, Tag::new(0, 0)),
        Err(TransportError::NoSuchRank { rank: 1, ranks: 1 })
    );
    assert!(
        s.recv(0, Tag::new(0, 0)).is_err(),
        "a group of one cannot wait for a message it never sent"
    );
}

/// Every rank sends PER_TAG messages of class 0 under two tags to every rank, then takes them with
/// `try_recv_any(0)` in whatever order they come: each arrives once, whole, in send order per (sender,
/// tag), and no class-3 message is taken.
fn any_source(t: &dyn Transport) {
    let r = t.ranks();
    let tags = [TAGS[0], TAGS[1]];
    for to in 0..r {
        t.send(to, TAGS[2], message(t.rank(), to, TAGS[2], 0)).expect("send");
        for tag in tags {
            for k in 0..PER_TAG {
                t.send(to, tag, message(t.rank(), to, tag, k)).expect("send");
            }
        }
    }
    let mut next = std::collections::HashMap::new();
    let mut got = 0;
    while got < r * tags.len() * PER_TAG {
        t.poll().expect("poll");
        let Some((from, tag, bytes)) = t.try_recv_any(0).expect("try_recv_any") else {
            std::thread::yield_now();
            continue;
        };
        assert_eq!(tag.class, 0);
        let k = next.entry((from, tag)).or_insert(0usize);
        assert_eq!(
            bytes,
            message(from, t.rank(), tag, *k),
            "rank {} from {from} {tag:?}",
            t.rank()
        );
        *k += 1;
        got += 1;
    }
    assert_eq!(t.try_recv_any(0).expect("try_recv_any"), None);
    for from in 0..r {
        assert_eq!(
            t.recv(from, TAGS[2]).expect("recv"),
            message(from, t.rank(), TAGS[2], 0)
        );
    }
}

#[test]
fn messages_of_a_class_come_from_any_sender_in_order_per_sender_and_tag() {
    for ranks in [1, 2, 3, 5] {
        run_loopback(ranks, None, |t| any_source(t));
        let delays = Some(Delays {
            seed: 7,
            max: Duration::from_micros(300),
        });
        run_loopback(ranks, delays, |t| any_source(t));
    }
    any_source(&SingleRank::new());
}

/// A rank parked as its driver is woken by a message for it.
#[test]
fn a_message_unparks_the_receivers_waker() {
    run_loopback(2, None, |t| {
        if t.rank() == 1 {
            t.set_waker(std::thread::current());
            t.allreduce_u64(&mut [0], IntOp::Sum).expect("barrier");
            let start = std::time::Instant::now();
            while t.try_recv(0, TAGS[0]).expect("try_recv").is_none() {
                std::thread::park_timeout(Duration::from_secs(5));
                assert!(start.elapsed() < Duration::from_secs(4), "never woken");
            }
        } else {
            t.allreduce_u64(&mut [0], IntOp::Sum).expect("barrier");
            std::thread::sleep(Duration::from_millis(20));
            t.send(1, TAGS[0], vec![1]).expect("send");
        }
    });
}
