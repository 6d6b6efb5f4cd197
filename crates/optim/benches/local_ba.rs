//! Local bundle adjustment at ORB-SLAM scale: 10 free + 5 fixed keyframes, 3000 points,
//! ~15000 monocular observations (1 px noise), seeded.

#[path = "../tests/common/mod.rs"]
mod common;

use common::{scene, SceneSpec};
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use ferroslam_optim::{local_bundle_adjust, SymbolicBa};

const SPEC: SceneSpec = SceneSpec {
    seed: 2024,
    poses: 15,
    fixed: 5,
    points: 3000,
    visibility: 0.375,
    stereo_fraction: 0.0,
    pixel_sigma: 1.0,
    pose_sigma_t: 0.02,
    pose_sigma_r: 0.005,
    point_sigma: 0.05,
};

fn local_ba(c: &mut Criterion) {
    let s = scene(&SPEC);
    let p = &s.problem;
    let symbolic = SymbolicBa::new(p).unwrap();
    eprintln!(
        "local BA scene: {} poses ({} free), {} points ({} optimised), {} observations, S nnz {}",
        p.poses.len(),
        symbolic.num_free_poses(),
        p.points.len(),
        symbolic.num_optimized_points(),
        p.observations.len(),
        symbolic.reduced_system_nnz()
    );
    let mut group = c.benchmark_group("local_ba");
    group.sample_size(20);
    group.bench_function("symbolic_analysis", |b| {
        b.iter(|| SymbolicBa::new(p).unwrap())
    });
    group.bench_function("local_bundle_adjust", |b| {
        b.iter_batched(
            || p.clone(),
            |mut problem| local_bundle_adjust(&mut problem).unwrap(),
            BatchSize::LargeInput,
        )
    });
    group.finish();
}

criterion_group!(benches, local_ba);
criterion_main!(benches);
