//! Visual-inertial local BA of a typical window: 15 free keyframes and 1 fixed, 1500 points
//! seen monocularly (1 px noise), 200 Hz IMU with EuRoC noise between keyframes 0.1 s apart
//! (the seeded flight of `tests/common/flight.rs`), started from perturbed poses (2 cm,
//! 0.3 deg), velocities (5 cm/s) and points (2 cm), zero biases.

#[path = "../tests/common/mod.rs"]
mod common;

use common::flight::flight;
use common::{gaussian3, perturb};
use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use ferroslam_optim::{inertial_bundle_adjust, InertialBaOptions};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn inertial_ba(c: &mut Criterion) {
    let (mut p, truth) = flight(6, 16, 1500);
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    for k in 1..p.visual.poses.len() {
        p.visual.poses[k] = perturb(&mut rng, &p.visual.poses[k], 0.02, 0.005);
        p.velocities[k] += gaussian3(&mut rng, 0.05);
    }
    for x in &mut p.visual.points {
        *x += gaussian3(&mut rng, 0.02);
    }
    let options = InertialBaOptions::default();
    let mut solved = p.clone();
    let report = inertial_bundle_adjust(&mut solved, &options)
        .unwrap()
        .report;
    let position_error_m = solved
        .visual
        .poses
        .iter()
        .zip(&truth.poses)
        .map(|(a, b)| (a.inverse().translation.vector - b.inverse().translation.vector).norm())
        .fold(0.0, f64::max);
    eprintln!(
        "inertial BA window: {} keyframes, {} points, {} observations; {} iterations, largest \
         camera position error {position_error_m:.4} m",
        p.visual.poses.len(),
        p.visual.points.len(),
        p.visual.observations.len(),
        report.iterations,
    );
    let mut group = c.benchmark_group("inertial_ba");
    group.sample_size(20);
    group.bench_function("inertial_bundle_adjust 16 keyframes 1500 points", |b| {
        b.iter_batched(
            || p.clone(),
            |mut problem| inertial_bundle_adjust(&mut problem, &options).unwrap(),
            BatchSize::LargeInput,
        )
    });
    group.finish();
}

criterion_group!(benches, inertial_ba);
criterion_main!(benches);
