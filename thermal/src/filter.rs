//! First-order lags of an input series, with heating and cooling time constants.

/// The input passed through a first-order lag starting at rest on its first value.
///
/// `tau_heat_s` applies while the input is above the lagged value (it is heating the
/// lagged value), `tau_cool_s` while it is below. A time constant of 0 passes the input
/// through. Each step is exact for an input held at the mean of its two readings.
/// `x` smoothed without delay: the first-order filter of time constant `tau_s` run forward,
/// then backward over the result (a centred smoother; `tau_s` <= 0: `x` itself).
pub(crate) fn zero_phase(time_s: &[f64], x: &[f64], tau_s: f64) -> Vec<f64> {
    if tau_s <= 0.0 {
        return x.to_vec();
    }
    let fwd = lag_held(time_s, x, tau_s, tau_s, 0.5);
    let rev_t: Vec<f64> = time_s.iter().rev().map(|t| -t).collect();
    let rev_x: Vec<f64> = fwd.iter().rev().copied().collect();
    let mut out = lag_held(&rev_t, &rev_x, tau_s, tau_s, 0.5);
    out.reverse();
    out
}

#[cfg(test)]
pub(crate) fn lag(time_s: &[f64], x: &[f64], tau_heat_s: f64, tau_cool_s: f64) -> Vec<f64> {
    lag_held(time_s, x, tau_heat_s, tau_cool_s, 0.5)
}

/// As [`lag`], with the input over a step taken as `w` × its first reading + (1 − `w`) × its
/// second: 0.5 for a change halfway between readings, 1 for a reading that holds until the
/// next one (a logged speed that changed at its reading).
pub(crate) fn lag_held(
    time_s: &[f64],
    x: &[f64],
    tau_heat_s: f64,
    tau_cool_s: f64,
    w: f64,
) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    let Some(&first) = x.first() else { return out };
    let mut y = first;
    out.push(y);
    for k in 1..x.len() {
        let dt = time_s[k] - time_s[k - 1];
        let tau = if x[k] >= y { tau_heat_s } else { tau_cool_s };
        // A change between two readings happened, on average, halfway between them: the
        // input over the step is taken as the mean of its two ends (a speed logged at the
        // new value has run at it for about half the step).
        let u = w * x[k - 1] + (1.0 - w) * x[k];
        y = if tau <= 0.0 {
            x[k]
        } else {
            y + (1.0 - (-dt / tau).exp()) * (u - y)
        };
        out.push(y);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_phase_smoothing_keeps_a_ramp_in_place() {
        // A centred smoother leaves a straight line where it is (a lag would shift it by τ).
        let t: Vec<f64> = (0..400).map(|i| i as f64 * 60.0).collect();
        let x: Vec<f64> = t.iter().map(|&t| 1e-3 * t).collect();
        let y = zero_phase(&t, &x, 600.0);
        for k in 100..300 {
            // (1e-4: the steps' trapezoid input, against a 0.6 shift for the lag below)
            assert!((y[k] - x[k]).abs() < 1e-4, "{k}: {} vs {}", y[k], x[k]);
        }
        let lagged = lag_held(&t, &x, 600.0, 600.0, 0.5);
        assert!((lagged[200] - x[200] + 0.6).abs() < 1e-3);
    }

    #[test]
    fn step_response_is_exponential() {
        let t: Vec<f64> = (0..200).map(|i| i as f64 * 10.0).collect();
        let x: Vec<f64> = t.iter().map(|&t| if t > 0.0 { 1.0 } else { 0.0 }).collect();
        let y = lag(&t, &x, 300.0, 300.0);
        for (k, v) in y.iter().enumerate().skip(1) {
            // Half the step over the first interval, then the whole: exact.
            let y1 = 0.5 * (1.0 - (-10.0f64 / 300.0).exp());
            let expect = 1.0 - (1.0 - y1) * (-(t[k] - 10.0) / 300.0).exp();
            assert!((v - expect).abs() < 1e-12, "{k}: {v} vs {expect}");
        }
    }

    #[test]
    fn heating_and_cooling_use_their_own_time_constants() {
        let t: Vec<f64> = (0..2000).map(|i| i as f64).collect();
        let x: Vec<f64> = t
            .iter()
            .map(|&t| if (1.0..1000.0).contains(&t) { 1.0 } else { 0.0 })
            .collect();
        let y = lag(&t, &x, 100.0, 400.0);
        // The step is seen half a sample late (a change halfway between readings).
        assert!((y[100] - (1.0 - (-0.995f64).exp())).abs() < 1e-4);
        let top = y[999];
        assert!((y[1399] - top * (-0.99875f64).exp()).abs() < 1e-4);
    }

    #[test]
    fn zero_tau_passes_through() {
        let t = [0.0, 1.0, 3.0];
        assert_eq!(lag(&t, &[1.0, 5.0, -2.0], 0.0, 0.0), vec![1.0, 5.0, -2.0]);
    }
}
