//! Named unit conversions.
//!
//! volver computes in mm, rad and s; reports and files use µm, µrad, µm/m (ppm), degrees and
//! hours. Every conversion between them goes through one of these constants, so a factor in the
//! code says which units it converts: `x_mm * UM_PER_MM` is a length in µm, `t_s / S_PER_H` a time
//! in hours.
//!
//! ```
//! use volver_core::units::{UM_PER_MM, URAD_PER_RAD};
//! let deviation_um = 0.0042 * UM_PER_MM;
//! assert!((deviation_um - 4.2).abs() < 1e-12);
//! assert_eq!(1.5e-6 * URAD_PER_RAD, 1.5);
//! ```

/// µm in one mm (a length in mm × this = the length in µm).
pub const UM_PER_MM: f64 = 1e3;

/// mm in one m (a length in m × this = the length in mm).
pub const MM_PER_M: f64 = 1e3;

/// µrad in one rad (an angle in rad × this = the angle in µrad).
pub const URAD_PER_RAD: f64 = 1e6;

/// Parts per million in one (a dimensionless ratio × this = the ratio in ppm, i.e. µm/m).
pub const PPM: f64 = 1e6;

/// Seconds in one hour (a time in s ÷ this = the time in h; a rate per s × this = per h).
pub const S_PER_H: f64 = 3600.0;

/// µs in one s.
pub const US_PER_S: f64 = 1e6;

/// ms in one s.
pub const MS_PER_S: f64 = 1e3;

/// The smallest positive value a ratio's denominator is floored at, so that a zero norm, cost or
/// variance divides to a large finite number instead of infinity or NaN (`x / d.max(TINY)`).
pub const TINY: f64 = 1e-300;
