//! Uncertainty evaluation: GUM (JCGM 100) and Monte Carlo (JCGM 101).
