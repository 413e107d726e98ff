//! The measurement model every method evaluates.

/// A measurement model Y = f(X): `evaluate` writes the outputs for the input values `x`.
pub trait Model: Sync {
    fn n_outputs(&self) -> usize;
    fn evaluate(&self, x: &[f64], y: &mut [f64]);
}

/// A model given as a closure.
pub struct FnModel<F> {
    pub n_outputs: usize,
    pub f: F,
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> Model for FnModel<F> {
    fn n_outputs(&self) -> usize {
        self.n_outputs
    }
    fn evaluate(&self, x: &[f64], y: &mut [f64]) {
        (self.f)(x, y)
    }
}
