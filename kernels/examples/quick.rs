use blockflow_kernels::*;
use std::time::Instant;
fn run<T: Real>(n: usize) {
    let l = Layout::new::<T>([n, n, n]);
    let mut a = PdfField::<T>::new(l, 0);
    let mut b = PdfField::<T>::new(l, 2048 + 96);
    let segs = sweep::full_segments(&l);
    let p = TrtParams {
        tau: 0.6,
        magic: 3.0 / 16.0,
        force: [0.0; 3],
    };
    for v in a.data_mut().iter_mut() {
        *v = T::from_f64(0.0);
    }
    for v in b.data_mut().iter_mut() {
        *v = T::from_f64(0.0);
    }
    sweep::stream_collide(&a, &mut b, &segs, &p);
    let reps = if n < 64 {
        4_000_000 / (n * n * n) * 10
    } else {
        10
    };
    let t = Instant::now();
    for _ in 0..reps / 2 {
        sweep::stream_collide(&a, &mut b, &segs, &p);
        sweep::stream_collide(&b, &mut a, &segs, &p);
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "{} {}^3: {:.1} MLUPS",
        T::NAME,
        n,
        (n * n * n * reps) as f64 / s / 1e6
    );
}
fn main() {
    run::<f64>(128);
    run::<f32>(128);
    run::<f64>(16);
    run::<f64>(128);
    run::<f32>(128);
}
