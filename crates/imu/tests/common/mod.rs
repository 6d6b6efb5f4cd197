//! Loading the REAL EuRoC V1_01_easy IMU and its vicon2gt ground truth, shared by the
//! real-data tests.
//!
//! Data: `$FERROSLAM_DATA/euroc/V1_01_easy_imu_gt`, else `../../../shared/data/...` relative
//! to this crate (see that folder's README). Missing data fails the test loudly.

// Each test binary uses a different part of this module.
#![allow(dead_code, non_snake_case)]

use std::path::PathBuf;

use ferroslam_imu::{Bias, ImuMeasurement, ImuState, NavState, Preintegrated};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

pub fn data_dir() -> PathBuf {
    std::env::var_os("FERROSLAM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"))
        .join("euroc/V1_01_easy_imu_gt")
}

/// A file of the data folder as text; panics with a hint if it is missing.
pub fn read(name: &str) -> String {
    let path = data_dir().join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (set FERROSLAM_DATA to the data folder)",
            path.display()
        )
    })
}

/// Numeric rows of a comma-separated file, skipping `#` comment lines. The first column
/// (nanoseconds) is returned separately as an integer so no precision is lost.
pub fn read_csv(name: &str) -> Vec<(i64, Vec<f64>)> {
    read(name)
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let mut fields = l.split(',').map(str::trim);
            let ns = fields.next().unwrap().parse::<i64>().unwrap();
            (ns, fields.map(|f| f.parse::<f64>().unwrap()).collect())
        })
        .collect()
}

/// One vicon2gt sample (20 Hz).
pub struct GroundTruth {
    /// Seconds since the first IMU sample.
    pub t_s: f64,
    /// Body pose, velocity and biases.
    pub state: ImuState,
}

impl GroundTruth {
    pub fn nav_state(&self) -> NavState {
        NavState {
            R_w_b: self.state.T_w_b.rotation,
            v_w_b: self.state.v_w_b,
            p_w_b: self.state.T_w_b.translation.vector,
        }
    }

    pub fn bias(&self) -> Bias {
        self.state.bias
    }
}

/// The real IMU stream and the vicon2gt states, times in seconds since the first IMU sample.
pub fn load() -> (Vec<ImuMeasurement>, Vec<GroundTruth>) {
    let imu_rows = read_csv("imu0/data.csv");
    let t0 = imu_rows[0].0;
    let seconds = |ns: i64| (ns - t0) as f64 * 1e-9;
    let imu = imu_rows
        .iter()
        .map(|(ns, r)| {
            ImuMeasurement::new(
                seconds(*ns),
                Vector3::new(r[0], r[1], r[2]),
                Vector3::new(r[3], r[4], r[5]),
            )
        })
        .collect();
    // vicon2gt: p xyz, q wxyz, v xyz, gyro bias xyz, accel bias xyz.
    let gt = read_csv("groundtruth_vicon2gt.csv")
        .iter()
        .map(|(ns, r)| GroundTruth {
            t_s: seconds(*ns),
            state: ImuState {
                T_w_b: Isometry3::from_parts(
                    Translation3::new(r[0], r[1], r[2]),
                    UnitQuaternion::from_quaternion(Quaternion::new(r[3], r[4], r[5], r[6])),
                ),
                v_w_b: Vector3::new(r[7], r[8], r[9]),
                bias: Bias::new(
                    Vector3::new(r[10], r[11], r[12]),
                    Vector3::new(r[13], r[14], r[15]),
                ),
            },
        })
        .collect();
    (imu, gt)
}

/// Median and maximum (sorted copy); NaN for an empty slice.
pub fn median_max(v: &[f64]) -> (f64, f64) {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    match v.last() {
        Some(&max) => (v[v.len() / 2], max),
        None => (f64::NAN, f64::NAN),
    }
}

/// Gravity in the vicon world fitted by least squares over windows `(start, end,
/// preintegration)`: `v_j - v_i - R_i dv(b_i) = g dt`, with `dv` corrected to first order to
/// the ground-truth bias at the start. The vicon world's z is tilted by ~0.24 deg, so the
/// nominal `(0, 0, -9.81)` leaves a constant 0.04 m/s^2 in every velocity residual.
pub fn fitted_gravity<'a>(
    windows: impl IntoIterator<Item = (&'a GroundTruth, &'a GroundTruth, &'a Preintegrated)>,
) -> Vector3<f64> {
    let (num, den) =
        windows
            .into_iter()
            .fold((Vector3::zeros(), 0.0), |(num, den), (a, b, pre)| {
                let d = pre.corrected(&a.bias());
                let lhs = b.state.v_w_b - a.state.v_w_b - a.state.T_w_b.rotation * d.delta_v;
                (num + lhs * d.dt, den + d.dt * d.dt)
            });
    num / den
}
