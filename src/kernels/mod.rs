//! Per-frame image kernels. Each operation has one name shared by its WGSL file (`shaders/`), its
//! Rust module, its params struct and its OpenCV twin (the `opencv` function of the module), and
//! the two are compared in tests within the bounds of [`tolerance`].

pub mod gray;
pub mod laplacian;
pub mod reduce;
pub mod sharpness;
pub mod tenengrad;
pub mod tolerance;

/// Every WGSL stage with its name, for validation and for `keyframer info`.
pub const SHADERS: &[(&str, &str)] = &[
    ("gray", gray::WGSL),
    ("tenengrad", tenengrad::WGSL),
    ("laplacian", laplacian::WGSL),
    ("reduce", reduce::WGSL),
];

/// Workgroups for `n` invocations of a 1-D kernel with 256 per group, folded into 2-D so no
/// dimension exceeds the 65 535 limit: (groups_x, groups_y).
pub fn groups_1d(n: u32) -> (u32, u32) {
    let groups = n.div_ceil(256).max(1);
    let x = groups.min(65_535);
    (x, groups.div_ceil(x))
}

/// Workgroups for a 16x16 tiled 2-D kernel over `width` x `height`.
pub fn groups_2d(width: u32, height: u32) -> (u32, u32) {
    (width.div_ceil(16), height.div_ceil(16))
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
        assert_eq!(super::groups_1d(37 * 83), (12, 1));
        assert_eq!(super::groups_1d(3840 * 2160), (32_400, 1));
        assert_eq!(super::groups_1d(65_536 * 256), (65_535, 2));
        assert_eq!(super::groups_2d(641, 359), (41, 23));
    }
}
