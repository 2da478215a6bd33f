use super::fmt;

#[test]
fn numbers_keep_one_decimal_and_drop_trailing_zeros() {
    assert_eq!(fmt(10.0), "10.0");
    assert_eq!(fmt(0.003), "0.003");
    assert_eq!(fmt(-0.0), "0.0");
    assert_eq!(fmt(-1e-10), "0.0");
    assert_eq!(fmt(-0.0125), "-0.0125");
    assert_eq!(fmt(1.0 / 3.0), "0.333333333");
}
