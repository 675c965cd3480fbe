//! The comparison behind every gradient check of the workspace: analytic gradients against
//! central finite differences.

/// Largest element-wise relative error `|a − n| / max(|a|, |n|, 1e-6)` between an analytic
/// gradient `analytic` and a numeric one `numeric` (same length; extra elements of the longer
/// slice are ignored). The absolute floor of `1e-6` keeps exact zeros comparable. 0 for empty
/// slices.
pub fn max_rel_err(analytic: &[f64], numeric: &[f64]) -> f64 {
    analytic
        .iter()
        .zip(numeric)
        .map(|(&a, &n)| (a - n).abs() / a.abs().max(n.abs()).max(1e-6))
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::max_rel_err;

    #[test]
    fn relative_with_an_absolute_floor() {
        assert_eq!(max_rel_err(&[], &[]), 0.0);
        assert!((max_rel_err(&[1.0, 2.0], &[1.0, 2.2]) - 0.2 / 2.2).abs() < 1e-15);
        // Both near zero: measured against the floor, not against each other.
        assert!((max_rel_err(&[1e-9], &[-1e-9]) - 2e-3).abs() < 1e-12);
    }
}
