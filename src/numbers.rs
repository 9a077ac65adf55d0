//! The checks of plain numbers that every reader shares (flags, workflow keys, project fields,
//! step parameters): one rule, one message, whatever the caller names the value.

/// `v` when it is a finite number above 0.
pub fn positive(v: f64) -> Result<f64, String> {
    above_zero(v, "")
}

/// [`positive`] for a distance in pixels.
pub fn positive_px(v: f64) -> Result<f64, String> {
    above_zero(v, " of pixels")
}

/// `v` when it is a finite number of seconds (a clock offset: any sign).
pub fn seconds(v: f64) -> Result<f64, String> {
    match v.is_finite() {
        true => Ok(v),
        false => Err(format!("must be a number of seconds, got {v}")),
    }
}

/// `v` when it is a finite number of seconds, 0 or more.
pub fn non_negative_seconds(v: f64) -> Result<f64, String> {
    match v.is_finite() && v >= 0.0 {
        true => Ok(v),
        false => Err(format!("must be a non-negative number of seconds, got {v}")),
    }
}

fn above_zero(v: f64, unit: &str) -> Result<f64, String> {
    match v.is_finite() && v > 0.0 {
        true => Ok(v),
        false => Err(format!("must be a positive number{unit}, got {v}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_rule_refuses_with_its_message() {
        assert_eq!(positive(0.5), Ok(0.5));
        for v in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                positive(v),
                Err(format!("must be a positive number, got {v}"))
            );
        }
        assert_eq!(
            positive_px(0.0),
            Err("must be a positive number of pixels, got 0".into())
        );
        assert_eq!(seconds(-2.0), Ok(-2.0));
        assert_eq!(
            seconds(f64::NAN),
            Err("must be a number of seconds, got NaN".into())
        );
        assert_eq!(non_negative_seconds(0.0), Ok(0.0));
        assert_eq!(
            non_negative_seconds(-1.0),
            Err("must be a non-negative number of seconds, got -1".into())
        );
    }
}
