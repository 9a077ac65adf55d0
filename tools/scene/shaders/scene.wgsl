// scene.wgsl: draws the synthetic drone scene (height-field terrain and textured boxes) for one
// shutter sub-sample, with a pinhole projection baked into `cam.clip` (see src/scene/render.rs:
// clip = P * V, OpenCV camera axes, wgpu depth range [0, 1]).
// Bindings: group 0: 0 camera (uniform, dynamic offset per sub-sample), 1 terrain texture,
//           2 object atlas, 3 trilinear sampler.
// Vertex buffers: 0 per vertex (position, normal, uv), 1 per instance (model matrix columns,
//                 atlas rectangle, tint rgb + kind in w: 0 terrain, 1 textured box, 2 unlit marker,
//                 3 wall: a box whose faces show the terrain texture, each face its own part of it).
// Output: rgba8unorm colour (averaged over sub-samples by scene_accum.wgsl), depth32float.

struct Camera {
    clip: mat4x4<f32>,
    sun: vec4<f32>,
};

@group(0) @binding(0) var<uniform> cam: Camera;
@group(0) @binding(1) var terrain_tex: texture_2d<f32>;
@group(0) @binding(2) var atlas_tex: texture_2d<f32>;
@group(0) @binding(3) var samp: sampler;

struct VIn {
    @location(0) pos: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) m0: vec4<f32>,
    @location(4) m1: vec4<f32>,
    @location(5) m2: vec4<f32>,
    @location(6) m3: vec4<f32>,
    @location(7) rect: vec4<f32>,
    @location(8) tint: vec4<f32>,
};

struct VOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) tint: vec4<f32>,
};

@vertex
fn vs_main(v: VIn) -> VOut {
    let model = mat4x4<f32>(v.m0, v.m1, v.m2, v.m3);
    let world = model * vec4<f32>(v.pos, 1.0);
    var out: VOut;
    out.clip = cam.clip * world;
    out.world = world.xyz;
    // Box faces have axis-aligned normals, so the model matrix keeps their direction.
    out.normal = normalize((model * vec4<f32>(v.normal, 0.0)).xyz);
    out.uv = v.rect.xy + v.uv * v.rect.zw;
    out.tint = v.tint;
    return out;
}

fn hash2(p: vec2<i32>) -> f32 {
    var h = u32(p.x) * 747796405u + u32(p.y) * 2891336453u + 12345u;
    h = ((h >> ((h >> 28u) + 4u)) ^ h) * 277803737u;
    h = (h >> 22u) ^ h;
    return f32(h) / 4294967295.0;
}

// Value noise in [0, 1] with a smooth fade (non-periodic over the terrain).
fn value_noise(x: vec2<f32>) -> f32 {
    let i = floor(x);
    let f = x - i;
    let u = f * f * (3.0 - 2.0 * f);
    let ii = vec2<i32>(i);
    let a = hash2(ii);
    let b = hash2(ii + vec2<i32>(1, 0));
    let c = hash2(ii + vec2<i32>(0, 1));
    let d = hash2(ii + vec2<i32>(1, 1));
    return mix(mix(a, b, u.x), mix(c, d, u.x), u.y);
}

// Offset of a wall face's part of the terrain texture, by the face's (axis-aligned) normal: the
// six faces' parts do not overlap for instance rectangles within the grid of world.rs.
fn wall_shift(n: vec3<f32>) -> vec2<f32> {
    return vec2<f32>(0.22 * n.x + 0.39 * n.y, -0.28 * n.x + 0.17 * n.y + 0.31 * n.z);
}

@fragment
fn fs_main(in: VOut) -> @location(0) vec4<f32> {
    // Sample the textures in uniform control flow, then pick by kind.
    let n = normalize(in.normal);
    let ground = textureSample(terrain_tex, samp, in.uv).rgb;
    let photo = textureSample(atlas_tex, samp, in.uv).rgb;
    let wall = textureSample(terrain_tex, samp, in.uv + wall_shift(round(n))).rgb;
    let footprint = length(fwidth(in.world.xy));
    let along = vec2<f32>(in.world.x + in.world.y, in.world.z);
    let wall_footprint = length(fwidth(along));
    let kind = in.tint.w;
    let light = 0.42 + 0.68 * max(dot(n, cam.sun.xyz), 0.0);
    // Walls and the ground near a walker: finer detail (cells of 9 and 29 cm), unique everywhere.
    let wall_fine = value_noise(along * 11.0) - 0.5;
    let wall_mid = value_noise(along * 3.4 + vec2<f32>(5.0, 3.0)) - 0.5;
    let near_fine = value_noise(in.world.xy * 11.0 + vec2<f32>(13.0, 7.0)) - 0.5;
    if (kind > 2.5) {
        let d = 1.0 + 0.45 * wall_fine * clamp(1.0 - wall_footprint * 8.0, 0.0, 1.0)
            + 0.4 * wall_mid * clamp(1.0 - wall_footprint * 2.5, 0.0, 1.0);
        return vec4<f32>(clamp(wall * in.tint.rgb * d * light, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
    }
    if (kind > 1.5) {
        return vec4<f32>(in.tint.rgb, 1.0);
    }
    if (kind > 0.5) {
        return vec4<f32>(clamp(photo * in.tint.rgb * light, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
    }
    // Terrain: photo patchwork plus fine detail noise that fades out where a pixel covers
    // more than about one noise cell (no aliasing at a distance).
    let fine = value_noise(in.world.xy * 3.1) - 0.5;
    let mid = value_noise(in.world.xy * 0.83 + vec2<f32>(37.0, 11.0)) - 0.5;
    let fade_fine = clamp(1.0 - footprint * 2.0, 0.0, 1.0);
    let fade_mid = clamp(1.0 - footprint * 0.5, 0.0, 1.0);
    let fade_near = clamp(1.0 - footprint * 8.0, 0.0, 1.0);
    let detail = 1.0 + 0.22 * fine * fade_fine + 0.16 * mid * fade_mid + 0.35 * near_fine * fade_near;
    return vec4<f32>(clamp(ground * detail * light, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
}
