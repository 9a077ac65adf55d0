//! Per-frame image kernels. Each operation has one name shared by its WGSL file (`shaders/`), its
//! Rust module, its params struct and its OpenCV twin (the `opencv` function of the module), and
//! the two are compared in tests within the bounds of [`tolerance`].

#[cfg(feature = "opencv")]
pub mod descriptor;
pub mod farneback;
#[cfg(feature = "opencv")]
pub mod gray;
pub mod laplacian;
pub mod movement;
pub mod remap;
pub mod resize_area;
pub mod sharpness;
pub mod sphere;
pub mod stationary;
pub mod strip;
pub mod tenengrad;
pub mod tolerance;

/// IEEE f64 arithmetic on u32 pairs, prepended to the shaders that decide in f64 as the host
/// does (movement, stationary).
pub const F64_WGSL: &str = include_str!("../../shaders/f64.wgsl");

/// Every WGSL stage with its name (the sharpness kernels with their strip.wgsl prelude), for
/// validation and for `keyframer info`.
pub const SHADERS: &[(&str, &str)] = &[
    ("tenengrad", tenengrad::WGSL),
    ("laplacian", laplacian::WGSL),
    ("farneback_pyramid", farneback::PYRAMID_WGSL),
    ("farneback_flow", farneback::FLOW_WGSL),
    ("movement", movement::WGSL),
    ("stationary", stationary::WGSL),
    ("copy", farneback::COPY_WGSL),
    ("resize_area", resize_area::WGSL),
    #[cfg(feature = "opencv")]
    ("descriptor", descriptor::WGSL),
    ("remap", remap::WGSL),
];

/// Words (4 gray pixels each) per row of a packed gray image of `width` pixels.
pub fn gray_stride(width: u32) -> u32 {
    width.div_ceil(4)
}

/// Validates a WGSL source with naga (no adapter needed); returns naga's message on failure.
pub fn validate_wgsl(source: &str) -> Result<(), String> {
    let module = naga::front::wgsl::parse_str(source).map_err(|e| e.emit_to_string(source))?;
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::empty(),
    )
    .validate(&module)
    .map(|_| ())
    .map_err(|e| format!("{e:?}"))
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_shader_validates() {
        for (name, src) in super::SHADERS {
            if let Err(e) = super::validate_wgsl(src) {
                panic!("{name}.wgsl: {e}");
            }
        }
    }

    #[test]
    fn dispatch_shapes() {
        assert_eq!(super::gray_stride(641), 161);
        assert_eq!(super::strip::groups(641, 359, 36), (6, 10));
        assert_eq!(super::strip::groups(3840, 2160, 36), (30, 60));
        assert_eq!(super::strip::texels_per_row(1920), 360);
        assert_eq!(super::strip::texels_per_row(641), 121);
    }
}
