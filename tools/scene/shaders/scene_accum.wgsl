// scene_accum.wgsl: motion blur by averaging shutter sub-samples, and the final 8-bit resolve.
// fs_accum reads the sub-sample colour texture (binding 0) at the same pixel; the pass blends it
// into an rgba16float accumulator with factor = blend constant (1 / K) and dst factor one.
// fs_resolve reads the accumulator (binding 0) and writes it to the rgba8unorm output.
// Both draw one full-screen triangle (vs_full, no vertex buffers).

@group(0) @binding(0) var src: texture_2d<f32>;

@vertex
fn vs_full(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs_accum(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    return textureLoad(src, vec2<i32>(p.xy), 0);
}

@fragment
fn fs_resolve(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    return textureLoad(src, vec2<i32>(p.xy), 0);
}
