//! Huber kernel on the squared, information-weighted error, as in g2o, and ORB-SLAM's
//! chi-square outlier thresholds.

/// 95% chi-square quantile with 2 degrees of freedom: monocular outlier threshold.
pub const CHI2_MONO: f64 = 5.991;
/// 95% chi-square quantile with 3 degrees of freedom: stereo outlier threshold.
pub const CHI2_STEREO: f64 = 7.815;
/// Huber width for monocular residuals, `sqrt(CHI2_MONO)`.
pub const HUBER_DELTA_MONO: f64 = 2.447_651_936_039_926_5;
/// Huber width for stereo residuals, `sqrt(CHI2_STEREO)`.
pub const HUBER_DELTA_STEREO: f64 = 2.795_532_149_698_872_5;

/// Outlier threshold for an observation with (`stereo = true`) or without a right coordinate.
pub fn chi2_threshold(stereo: bool) -> f64 {
    if stereo {
        CHI2_STEREO
    } else {
        CHI2_MONO
    }
}

/// Huber kernel applied to `chi2 = e^T Omega e` (g2o's `RobustKernelHuber`):
/// `rho(s) = s` for `s <= delta^2`, else `2 delta sqrt(s) - delta^2`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Huber {
    /// Width in units of sigma (the kernel is quadratic while `sqrt(chi2) <= delta`).
    pub delta: f64,
}

impl Huber {
    /// ORB-SLAM's kernel for an observation with (`stereo = true`) or without a right coordinate.
    pub fn for_observation(stereo: bool) -> Self {
        Self {
            delta: if stereo {
                HUBER_DELTA_STEREO
            } else {
                HUBER_DELTA_MONO
            },
        }
    }

    /// Robustified cost `rho(chi2)`.
    pub fn rho(&self, chi2: f64) -> f64 {
        let d2 = self.delta * self.delta;
        if chi2 <= d2 {
            chi2
        } else {
            2.0 * self.delta * chi2.sqrt() - d2
        }
    }

    /// Derivative `rho'(chi2)`, the IRLS weight applied to `J^T Omega J` and `J^T Omega e`.
    pub fn weight(&self, chi2: f64) -> f64 {
        if chi2 <= self.delta * self.delta {
            1.0
        } else {
            self.delta / chi2.sqrt()
        }
    }
}

/// Cost and IRLS weight of one observation's `chi2`, robust (Huber) or plain.
pub(crate) fn cost_and_weight(chi2: f64, stereo: bool, robust: bool) -> (f64, f64) {
    if robust {
        let h = Huber::for_observation(stereo);
        (h.rho(chi2), h.weight(chi2))
    } else {
        (chi2, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn widths_are_sqrt_of_thresholds() {
        assert_relative_eq!(HUBER_DELTA_MONO, CHI2_MONO.sqrt(), epsilon = 1e-15);
        assert_relative_eq!(HUBER_DELTA_STEREO, CHI2_STEREO.sqrt(), epsilon = 1e-15);
    }

    #[test]
    fn huber_is_continuous_and_weight_is_its_derivative() {
        let h = Huber { delta: 2.0 };
        assert_relative_eq!(h.rho(4.0 - 1e-12), h.rho(4.0 + 1e-12), epsilon = 1e-9);
        for s in [0.5, 3.9, 4.1, 30.0] {
            let eps = 1e-6;
            let numeric = (h.rho(s + eps) - h.rho(s - eps)) / (2.0 * eps);
            assert_relative_eq!(h.weight(s), numeric, epsilon = 1e-6);
        }
        // Linear growth in |e| beyond the width.
        assert_relative_eq!(h.rho(100.0), 2.0 * 2.0 * 10.0 - 4.0);
    }
}
