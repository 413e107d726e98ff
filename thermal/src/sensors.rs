//! What the temperature readings themselves show: noise, jumps, collinearity.

use nalgebra::DMatrix;

/// Short-term noise of a series: robust standard deviation of its first differences / √2.
pub(crate) fn short_term_noise(x: &[f64]) -> f64 {
    let mut d: Vec<f64> = x.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    1.4826 * d[d.len() / 2] / std::f64::consts::SQRT_2
}

/// Short-term noise of a series that moves: robust standard deviation of its second
/// differences / √6 (white noise σ gives second differences of variance 6σ²; a steady slope
/// adds nothing, where it widens the first differences).
pub(crate) fn short_term_noise_of_moving(x: &[f64]) -> f64 {
    let mut d: Vec<f64> = x
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).abs())
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    1.4826 * d[d.len() / 2] / 6f64.sqrt()
}

/// Jumps: differences beyond `k` robust scales of the differences that also stand out
/// `k/2` times from the typical difference around them (not a steep but smooth change).
pub(crate) fn jumps(x: &[f64], k: f64) -> usize {
    let d: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
    let scale = short_term_noise(x) * std::f64::consts::SQRT_2;
    if scale <= 0.0 {
        return 0;
    }
    (0..d.len())
        .filter(|&i| {
            let lo = i.saturating_sub(10);
            let hi = (i + 11).min(d.len());
            let mut near: Vec<f64> = (lo..hi).filter(|&j| j != i).map(|j| d[j].abs()).collect();
            near.sort_by(f64::total_cmp);
            let typical = near.get(near.len() / 2).copied().unwrap_or(0.0);
            d[i].abs() > k * scale && d[i].abs() > 0.5 * k * typical.max(scale / 1.4826)
        })
        .count()
}

/// Variance inflation factor of each series among the others (∞-free: capped at 1e12).
pub(crate) fn vifs(series: &[&[f64]]) -> Vec<f64> {
    let p = series.len();
    if p < 2 {
        return vec![1.0; p];
    }
    let n = series[0].len() as f64;
    let z: Vec<Vec<f64>> = series
        .iter()
        .map(|s| {
            let m = s.iter().sum::<f64>() / n;
            let sd = (s.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n)
                .sqrt()
                .max(1e-12);
            s.iter().map(|v| (v - m) / sd).collect()
        })
        .collect();
    let r = DMatrix::from_fn(p, p, |i, j| crate::cv::dot(&z[i], &z[j]) / n);
    match r.try_inverse() {
        Some(inv) => (0..p).map(|i| inv[(i, i)].clamp(1.0, 1e12)).collect(),
        None => vec![1e12; p],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// Gaussian noise of σ 0.1 on a curve that rises 0.15 a step (a displacement heating,
    /// as in the generator's fast runs), then bends over: the first differences' estimate
    /// widens with the slope, the second differences' stays at σ.
    #[test]
    fn the_noise_of_a_moving_series_ignores_its_slope() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = Normal::new(0.0, 0.1).expect("a normal");
        let x: Vec<f64> = (0..4000)
            .map(|i| 0.15 * (i.min(2000) as f64) + 30.0 * (1.0 - (-(i as f64) / 200.0).exp()))
            .map(|v| v + n.sample(&mut rng))
            .collect();
        let second = short_term_noise_of_moving(&x);
        assert!(
            (second / 0.1 - 1.0).abs() < 0.05,
            "second differences: {second}"
        );
        let flat: Vec<f64> = (0..4000).map(|_| n.sample(&mut rng)).collect();
        let ratio = short_term_noise_of_moving(&flat) / short_term_noise(&flat);
        assert!((ratio - 1.0).abs() < 0.05, "on a flat series: {ratio}");
        let first = short_term_noise(&x);
        assert!(first > 1.3 * 0.1, "first differences: {first}");
    }

    #[test]
    fn jumps_are_found_and_ramps_are_not() {
        let noise = |i: usize| 0.01 * (((i * 7919) % 101) as f64 / 50.0 - 1.0);
        let mut x: Vec<f64> = (0..500).map(|i| 20.0 + noise(i)).collect();
        assert_eq!(jumps(&x, 10.0), 0);
        for v in x.iter_mut().skip(250) {
            *v += 1.0;
        }
        assert_eq!(jumps(&x, 10.0), 1);
        let ramp: Vec<f64> = (0..500)
            .map(|i| {
                20.0 + noise(i)
                    + if i > 200 {
                        0.05 * (i - 200) as f64
                    } else {
                        0.0
                    }
            })
            .collect();
        assert_eq!(jumps(&ramp, 10.0), 0);
    }

    #[test]
    fn vif_of_near_copies_is_large() {
        let a: Vec<f64> = (0..300).map(|i| (i as f64 / 40.0).sin()).collect();
        let b: Vec<f64> = (0..300)
            .map(|i| (i as f64 / 40.0).sin() + 0.001 * ((i * 31) % 7) as f64)
            .collect();
        let c: Vec<f64> = (0..300).map(|i| (i as f64 / 13.0).cos()).collect();
        let v = vifs(&[&a, &b, &c]);
        assert!(v[0] > 1000.0 && v[1] > 1000.0 && v[2] < 2.0, "{v:?}");
    }
}
