//! Block serialisation (`blockflow::serialise`): bitwise round trips, bitwise continuation after every
//! block was wiped and rebuilt from its bytes (in place and in a fresh simulation, i.e. a restart), errors
//! for bad input, and `encoded_len`.

mod common;
use blockflow::physics::particle_cells::ParticleCells;
use blockflow::physics::particles::{Published, Work};
use blockflow::physics::simulation::Simulation;
use blockflow::serialise::{
    checksum, decode_block, encode_block, encoded_len, peek_header, FormatError, BLOCK_FORMAT_VERSION,
};
use blockflow::timeloop::TimeLoop;
use common::{cfg, checksums, sim64, timeloop};

/// The time loop of a scene (as `blockflow run` sets it up).
fn start(file: &str, sets: &[&str]) -> TimeLoop<f64> {
    timeloop(file, sets)
}

fn encode_all(sim: &Simulation<f64>) -> Vec<Vec<u8>> {
    (0..sim.blocks.len())
        .map(|id| {
            let mut v = Vec::new();
            encode_block(sim, id, &mut v);
            v
        })
        .collect()
}

/// Overwrites everything a decode must restore: both PDF fields with NaN, the overlay with an empty one,
/// the block's published lists and rigid-body result with empty ones.
fn wipe(sim: &Simulation<f64>) {
    for b in &sim.blocks {
        for p in 0..2 {
            let mut f = b.fresh_field(p);
            f.data_mut().fill(f64::NAN);
            // SAFETY: nothing runs.
            unsafe { b.replace_field(p, f) };
        }
        if b.particle_cells().is_some() {
            // SAFETY: as above.
            unsafe { b.replace_particle_cells(Some(ParticleCells::default())) };
        }
    }
    if let Some(parts) = &sim.particles {
        for pb in &parts.blocks {
            // SAFETY: as above.
            unsafe {
                pb.replace_published(0, Published::default());
                pb.replace_published(1, Published::default());
                pb.replace_work(Work::default());
            }
        }
    }
}

fn decode_all(sim: &Simulation<f64>, bytes: &[Vec<u8>]) {
    for (id, b) in bytes.iter().enumerate() {
        // SAFETY: nothing runs.
        unsafe { decode_block(sim, id, b) }.unwrap_or_else(|e| panic!("block {id}: {e}"));
    }
}

/// encode → decode into the same simulation → encode: identical bytes for every block, `encoded_len`
/// equal to the length, and the checksums unchanged.
fn round_trip(file: &str, sets: &[&str], steps: u64) {
    let mut tl = start(file, sets);
    tl.advance(steps).expect("stable");
    let sim = tl.sim();
    let before = checksums(sim);
    for id in 0..sim.blocks.len() {
        let mut a = Vec::new();
        encode_block(sim, id, &mut a);
        assert_eq!(encoded_len(sim, id), a.len(), "{file} block {id}: encoded_len");
        let h = peek_header(&a).unwrap();
        assert_eq!((h.id, h.step, h.total_len), (id, steps, a.len()));
        // SAFETY: nothing runs.
        unsafe { decode_block(sim, id, &a) }.unwrap_or_else(|e| panic!("{file} block {id}: {e}"));
        let mut b = Vec::new();
        encode_block(sim, id, &mut b);
        assert!(a == b, "{file} block {id}: bytes differ after a round trip");
    }
    assert_eq!(checksums(sim), before, "{file}: state changed by a round trip");
}

#[test]
fn round_trip_is_bitwise_taylor_green() {
    round_trip("taylor_green.toml", &[], 30);
}

#[test]
fn round_trip_is_bitwise_granular_box() {
    round_trip("granular_box.toml", &[], 30);
}

#[test]
fn round_trip_is_bitwise_hopper_small() {
    let tl = start("hopper-small.toml", &[]);
    let sim = tl.sim();
    // The coupled scene exercises every section: some blocks carry an overlay with covered cells.
    assert!(sim
        .blocks
        .iter()
        .any(|b| b.particle_cells().is_some_and(|pc| pc.owned())));
    round_trip("hopper-small.toml", &[], 30);
}

/// Runs `n1 + n2` steps straight, and again with every block encoded after `n1` steps, wiped and
/// decoded; the final checksums and every block's bytes are identical. With `restart`, the second run
/// decodes into a fresh simulation built from the scene (a checkpoint restart) instead.
fn continuation(file: &str, sets: &[&str], n1: u64, n2: u64, restart: bool) {
    let mut a = start(file, sets);
    a.advance(n1).expect("stable");
    a.advance(n2).expect("stable");
    let want = checksums(a.sim());

    let mut b = start(file, sets);
    b.advance(n1).expect("stable");
    let bytes = encode_all(b.sim());
    if restart {
        b = start(file, sets);
        b.sim_mut().step = n1;
        b.resume();
    }
    wipe(b.sim());
    decode_all(b.sim(), &bytes);
    b.advance(n2).expect("stable");
    assert_eq!(checksums(b.sim()), want, "{file}: continuation differs");
    let (ea, eb) = (encode_all(a.sim()), encode_all(b.sim()));
    let differ: Vec<usize> = (0..ea.len()).filter(|&id| ea[id] != eb[id]).collect();
    assert!(
        differ.is_empty(),
        "{file}: bytes of blocks {differ:?} differ after continuation"
    );
}

#[test]
fn continuation_is_bitwise_hopper_small() {
    continuation("hopper-small.toml", &[], 20, 20, false);
}

#[test]
fn continuation_is_bitwise_granular_box() {
    continuation("granular_box.toml", &[], 20, 20, false);
}

#[test]
fn continuation_is_bitwise_taylor_green() {
    continuation("taylor_green.toml", &[], 20, 20, false);
}

/// A restart into a fresh simulation at an odd step with an odd sub-step count (published lists of
/// parity 1), over several processes.
#[test]
fn restart_in_a_fresh_simulation_is_bitwise_hopper_small() {
    continuation(
        "hopper-small.toml",
        &["particles.subcycles=3", "processes.count=3"],
        21,
        19,
        true,
    );
}

#[test]
fn restart_in_a_fresh_simulation_is_bitwise_taylor_green() {
    continuation("taylor_green.toml", &[], 15, 10, true);
}

/// A 16³ fluid block in f64: header and table (76 bytes), PDFs (19 × 16³ × 8), flags with the ghost layer
/// (18³), checksum (8).
#[test]
fn encoded_len_of_a_16_cubed_fluid_block() {
    let sim = sim64("taylor_green.toml", &[]);
    assert_eq!(sim.domain.block_size, [16, 16, 16]);
    let mut v = Vec::new();
    encode_block(&sim, 0, &mut v);
    assert_eq!(v.len(), 76 + 19 * 4096 * 8 + 18 * 18 * 18 + 8);
    assert_eq!(encoded_len(&sim, 0), v.len());
    // Appends: a second block follows the first.
    encode_block(&sim, 1, &mut v);
    assert_eq!(v.len(), 2 * encoded_len(&sim, 0));
}

fn decode_err(sim: &Simulation<f64>, id: usize, bytes: &[u8]) -> FormatError {
    // SAFETY: nothing runs.
    unsafe { decode_block(sim, id, bytes) }.expect_err("bad input must be refused")
}

#[test]
fn bad_input_gives_the_matching_error() {
    let mut tl = start("hopper-small.toml", &[]);
    tl.advance(3).expect("stable");
    let sim = tl.sim();
    let id = (0..sim.blocks.len())
        .find(|&b| sim.blocks[b].particle_cells().is_some_and(|pc| pc.owned()))
        .expect("a block with particles");
    let mut good = Vec::new();
    encode_block(sim, id, &mut good);
    let n = good.len();

    // Truncated anywhere: never a panic, always an error; past the fixed header it says Truncated.
    for cut in (0..n).step_by(97).chain([n - 1, n - 8, 60, 49, 8, 4, 0]) {
        let e = decode_err(sim, id, &good[..cut]);
        assert!(matches!(e, FormatError::Truncated { .. }), "cut at {cut}: {e}");
    }
    assert_eq!(
        decode_err(sim, id, &good[..n - 1]),
        FormatError::Truncated {
            needed: n,
            found: n - 1
        }
    );
    // A flipped byte anywhere after the header's fixed fields: checksum error.
    for at in (17..n).step_by(331).chain([n - 1, n / 2]) {
        let mut bad = good.clone();
        bad[at] ^= 0x10;
        let e = decode_err(sim, id, &bad);
        assert!(matches!(e, FormatError::Checksum { .. }), "flip at {at}: {e}");
    }
    let mut bad = good.clone();
    bad[1] = b'X';
    assert_eq!(decode_err(sim, id, &bad), FormatError::BadMagic);
    let mut bad = good.clone();
    bad[5..9].copy_from_slice(&(BLOCK_FORMAT_VERSION + 1).to_le_bytes());
    assert_eq!(
        decode_err(sim, id, &bad),
        FormatError::Version {
            found: BLOCK_FORMAT_VERSION + 1,
            expected: BLOCK_FORMAT_VERSION
        }
    );
    // A consistent checksum over an inconsistent section table: malformed, not a panic.
    let mut bad = good.clone();
    let table_len_at = 50 + 1 + 3; // first section ("pdf"): its payload length
    let len = u64::from_le_bytes(bad[table_len_at..table_len_at + 8].try_into().unwrap());
    bad[table_len_at..table_len_at + 8].copy_from_slice(&(len + 8).to_le_bytes());
    let sum = checksum(&bad[..n - 8]);
    bad[n - 8..].copy_from_slice(&sum.to_le_bytes());
    assert!(matches!(decode_err(sim, id, &bad), FormatError::Malformed(_)));
    // Trailing bytes.
    let mut long = good.clone();
    long.push(0);
    assert!(matches!(decode_err(sim, id, &long), FormatError::Mismatch(_)));

    // Another block id, another geometry.
    let other = (id + 1) % sim.blocks.len();
    let e = decode_err(sim, other, &good);
    assert!(matches!(&e, FormatError::Mismatch(m) if m.contains("block")), "{e}");
    // After all the refused input the block is unchanged.
    let mut now = Vec::new();
    encode_block(sim, id, &mut now);
    assert!(now == good, "a refused decode changed the block");
    // Another step.
    tl.advance(1).expect("stable");
    let sim = tl.sim();
    let e = decode_err(sim, id, &good);
    assert!(matches!(&e, FormatError::Mismatch(m) if m.contains("step")), "{e}");

    // Another block size (same id, same precision).
    let tg = sim64("taylor_green.toml", &[]);
    assert_ne!(tg.domain.block_size, sim.domain.block_size);
    let mut tg_bytes = Vec::new();
    encode_block(&tg, 0, &mut tg_bytes);
    let small = sim64("taylor_green.toml", &["scene.resolution=16"]);
    assert_ne!(small.domain.block_size, tg.domain.block_size);
    let e = decode_err(&small, 0, &tg_bytes);
    assert!(
        matches!(&e, FormatError::Mismatch(m) if m.contains("block size")),
        "{e}"
    );

    // Another precision.
    let c = cfg("taylor_green.toml", &[]);
    let scene = blockflow::scenes::build(&c).unwrap();
    let tg32 = blockflow::timeloop::setup::build_sim::<f32>(&c, &scene).unwrap();
    let mut b32 = Vec::new();
    encode_block(&tg32, 0, &mut b32);
    assert_eq!(encoded_len(&tg32, 0), b32.len());
    let e = decode_err(&tg, 0, &b32);
    assert!(matches!(&e, FormatError::Mismatch(m) if m.contains("precision")), "{e}");
    // f32 round trip.
    // SAFETY: nothing runs.
    unsafe { decode_block(&tg32, 0, &b32) }.unwrap();
    let mut again = Vec::new();
    encode_block(&tg32, 0, &mut again);
    assert!(again == b32);

    // Particle state into a simulation without particles and the reverse.
    let e = decode_err(&tg, 0, &{
        let mut v = Vec::new();
        let gb = sim64("granular_box.toml", &[]);
        encode_block(&gb, 0, &mut v);
        v
    });
    assert!(matches!(e, FormatError::Mismatch(_)), "{e}");

    // Every message is one line naming the reason.
    for e in [
        FormatError::BadMagic,
        FormatError::Truncated { needed: 9, found: 3 },
        FormatError::Checksum { stored: 1, computed: 2 },
    ] {
        let s = e.to_string();
        assert!(!s.is_empty() && !s.contains('\n'), "{s}");
    }
    let _: &dyn std::error::Error = &FormatError::BadMagic;
}
