// copy.wgsl: dst = src, texel by texel (the stationary step keeps a frame's expansion pyramid as
// its reference; dispatched indirectly, so the device decides whether it runs).
// Bindings: 0 src, 1 dst (textures of one size). Workgroup 8 x 8, one texel per invocation.

@group(0) @binding(0) var src: texture_storage_2d<rgba32float, read>;
@group(0) @binding(1) var dst: texture_storage_2d<rgba32float, write>;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(src);
    if (id.x < size.x && id.y < size.y) {
        textureStore(dst, id.xy, textureLoad(src, id.xy));
    }
}
