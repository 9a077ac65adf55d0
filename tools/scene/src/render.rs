//! Offscreen wgpu renderer of a scene: one pipeline set, textures and buffers created once and
//! reused for every frame; each frame averages K shutter sub-samples (motion blur) in an rgba16float
//! accumulator and reads back tightly packed RGBA8 rows. The projection is the pinhole camera of
//! [`Intrinsics`] with OpenCV axes (x right, y down, z forward) and wgpu's [0, 1] depth range.

use super::math::{Pose, V3};
use super::world::{MipImage, Vertex, CHUNK_INDICES};
use keyframer::error::{Error, Result};
use keyframer::gpu::GpuContext;
use wgpu::util::DeviceExt;

/// Scene shader source.
pub const WGSL: &str = include_str!("../shaders/scene.wgsl");
/// Accumulation / resolve shader source.
pub const ACCUM_WGSL: &str = include_str!("../shaders/scene_accum.wgsl");

const NEAR: f64 = 0.5;
const FAR: f64 = 2000.0;
const SLOT: u64 = 256;

/// Pinhole intrinsics in pixels, COLMAP's convention: the image's top-left corner is (0, 0), so
/// the centre of pixel (i, j) is (i + 0.5, j + 0.5) and `cx = width / 2` is the image centre.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Intrinsics {
    /// Focal length in x (pixels).
    pub fx: f64,
    /// Focal length in y (pixels).
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
}

impl Intrinsics {
    /// Projects a camera-frame point (z forward) to continuous pixel coordinates.
    pub fn project(&self, p: V3) -> (f64, f64) {
        (self.fx * p.0 / p.2 + self.cx, self.fy * p.1 / p.2 + self.cy)
    }
}

/// Column-major clip matrix P * V for `pose` (camera-to-world) with `k` on a `w` x `h` target.
pub fn clip_matrix(pose: &Pose, k: &Intrinsics, w: u32, h: u32) -> [f32; 16] {
    let (w, h) = (w as f64, h as f64);
    let p = [
        [2.0 * k.fx / w, 0.0, 2.0 * k.cx / w - 1.0, 0.0],
        [0.0, -2.0 * k.fy / h, 1.0 - 2.0 * k.cy / h, 0.0],
        [0.0, 0.0, FAR / (FAR - NEAR), -NEAR * FAR / (FAR - NEAR)],
        [0.0, 0.0, 1.0, 0.0],
    ];
    let r = &pose.rot;
    let c = pose.centre;
    let v = [
        [r[0].0, r[0].1, r[0].2, -r[0].dot(c)],
        [r[1].0, r[1].1, r[1].2, -r[1].dot(c)],
        [r[2].0, r[2].1, r[2].2, -r[2].dot(c)],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let mut out = [0f32; 16];
    for col in 0..4 {
        for row in 0..4 {
            let s: f64 = (0..4).map(|i| p[row][i] * v[i][col]).sum();
            out[col * 4 + row] = s as f32;
        }
    }
    out
}

/// Index ranges of the terrain chunks (bounds from [`super::world::Terrain::chunk_bounds`]) that
/// may be visible from `pose`: a chunk is dropped only when all its corners lie behind the near
/// plane or beyond one side of the view frustum; neighbouring chunks are merged into one range.
pub fn visible_chunks(
    pose: &Pose,
    k: &Intrinsics,
    w: u32,
    h: u32,
    bounds: &[(V3, V3)],
) -> Vec<std::ops::Range<u32>> {
    let (w, h) = (w as f64, h as f64);
    let mut out: Vec<std::ops::Range<u32>> = Vec::new();
    for (n, (lo, hi)) in bounds.iter().enumerate() {
        let mut outside = [true; 5];
        for c in 0..8 {
            let p = V3(
                if c & 1 == 0 { lo.0 } else { hi.0 },
                if c & 2 == 0 { lo.1 } else { hi.1 },
                if c & 4 == 0 { lo.2 } else { hi.2 },
            );
            let q = pose.to_camera(p);
            // Planes: near, left, right, top, bottom (in camera coordinates, margin of 2 px).
            let tests = [
                q.2 > NEAR,
                (q.0 * k.fx + (k.cx + 2.0) * q.2) > 0.0,
                (q.0 * k.fx + (k.cx - w - 2.0) * q.2) < 0.0,
                (q.1 * k.fy + (k.cy + 2.0) * q.2) > 0.0,
                (q.1 * k.fy + (k.cy - h - 2.0) * q.2) < 0.0,
            ];
            for (o, inside) in outside.iter_mut().zip(tests) {
                *o &= !inside;
            }
        }
        if outside.iter().any(|&o| o) {
            continue;
        }
        let r = n as u32 * CHUNK_INDICES..(n as u32 + 1) * CHUNK_INDICES;
        match out.last_mut() {
            Some(last) if last.end == r.start => last.end = r.end,
            _ => out.push(r),
        }
    }
    out
}

/// One shutter sub-sample to render.
pub struct SubSample {
    /// Clip matrix ([`clip_matrix`]).
    pub clip: [f32; 16],
    /// Instances (terrain first).
    pub instances: Vec<Instance>,
    /// Terrain index ranges to draw ([`visible_chunks`]).
    pub terrain: Vec<std::ops::Range<u32>>,
}

/// Per-instance data (matches scene.wgsl locations 3..8).
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Instance {
    /// Model matrix, column-major.
    pub model: [f32; 16],
    /// Atlas rectangle: offset (x, y), size (w, h) in uv.
    pub rect: [f32; 4],
    /// Tint rgb and kind (0 terrain, 1 box, 2 marker).
    pub tint: [f32; 4],
}

impl Instance {
    /// A box of `size` at `centre` rotated by `yaw` about +z.
    pub fn boxed(centre: V3, yaw: f64, size: [f64; 3], rect: [f32; 4], tint: [f32; 4]) -> Instance {
        let (s, c) = yaw.sin_cos();
        let model = [
            (c * size[0]) as f32,
            (s * size[0]) as f32,
            0.0,
            0.0,
            (-s * size[1]) as f32,
            (c * size[1]) as f32,
            0.0,
            0.0,
            0.0,
            0.0,
            size[2] as f32,
            0.0,
            centre.0 as f32,
            centre.1 as f32,
            centre.2 as f32,
            1.0,
        ];
        Instance { model, rect, tint }
    }

    /// The terrain's instance (identity model, whole texture).
    pub fn terrain() -> Instance {
        let mut model = [0f32; 16];
        for i in 0..4 {
            model[i * 5] = 1.0;
        }
        Instance {
            model,
            rect: [0.0, 0.0, 1.0, 1.0],
            tint: [1.0, 1.0, 1.0, 0.0],
        }
    }
}

/// Everything needed to render frames of one scene at one size.
pub struct Renderer<'a> {
    ctx: &'a GpuContext,
    width: u32,
    height: u32,
    samples: u32,
    instances_per_slot: u32,
    scene_pipeline: wgpu::RenderPipeline,
    accum_pipeline: wgpu::RenderPipeline,
    resolve_pipeline: wgpu::RenderPipeline,
    scene_bind: wgpu::BindGroup,
    accum_bind: wgpu::BindGroup,
    resolve_bind: wgpu::BindGroup,
    camera_buf: wgpu::Buffer,
    instance_buf: wgpu::Buffer,
    terrain_vb: wgpu::Buffer,
    terrain_ib: wgpu::Buffer,
    terrain_count: u32,
    box_vb: wgpu::Buffer,
    box_ib: wgpu::Buffer,
    box_count: u32,
    sub_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    accum_view: wgpu::TextureView,
    out_tex: wgpu::Texture,
    out_view: wgpu::TextureView,
    readback: wgpu::Buffer,
    padded_row: u32,
}

/// Meshes and textures of a scene.
pub struct SceneData<'d> {
    /// Terrain mesh.
    pub terrain: (&'d [Vertex], &'d [u32]),
    /// Unit box mesh.
    pub boxes: (&'d [Vertex], &'d [u32]),
    /// Terrain texture with mips.
    pub terrain_tex: &'d MipImage,
    /// Object atlas with mips.
    pub atlas: &'d MipImage,
    /// Instances per sub-sample (terrain first).
    pub instances: u32,
}

fn upload_mips(ctx: &GpuContext, img: &MipImage, label: &str) -> wgpu::Texture {
    let tex = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: img.size,
            height: img.size,
            depth_or_array_layers: 1,
        },
        mip_level_count: img.levels.len() as u32,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    for (level, data) in img.levels.iter().enumerate() {
        let s = (img.size >> level).max(1);
        ctx.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &tex,
                mip_level: level as u32,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            data,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * s),
                rows_per_image: Some(s),
            },
            wgpu::Extent3d {
                width: s,
                height: s,
                depth_or_array_layers: 1,
            },
        );
    }
    tex
}

impl<'a> Renderer<'a> {
    /// Creates pipelines, uploads meshes and textures, allocates targets for `width` x `height`
    /// and `samples` sub-samples per frame.
    pub fn new(
        ctx: &'a GpuContext,
        data: &SceneData<'_>,
        width: u32,
        height: u32,
        samples: u32,
    ) -> Result<Renderer<'a>> {
        let lim = &ctx.limits;
        let biggest = data.terrain_tex.size.max(width).max(height);
        if biggest > lim.max_texture_dimension_2d {
            return Err(Error::gpu(format!(
                "the scene needs {biggest}-texel textures; the device allows {}",
                lim.max_texture_dimension_2d
            )));
        }
        let dev = &ctx.device;
        let terrain_tex = upload_mips(ctx, data.terrain_tex, "scene terrain texture");
        let atlas_tex = upload_mips(ctx, data.atlas, "scene atlas");
        let sampler = dev.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("scene sampler"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            anisotropy_clamp: 1,
            ..Default::default()
        });
        let camera_buf = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("scene cameras"),
            size: SLOT * samples as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let inst_size = std::mem::size_of::<Instance>() as u64;
        let instance_buf = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("scene instances"),
            size: inst_size * data.instances as u64 * samples as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let vb = |label: &str, bytes: &[u8], usage| {
            dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage,
            })
        };
        let terrain_vb = vb(
            "terrain vertices",
            bytemuck::cast_slice(data.terrain.0),
            wgpu::BufferUsages::VERTEX,
        );
        let terrain_ib = vb(
            "terrain indices",
            bytemuck::cast_slice(data.terrain.1),
            wgpu::BufferUsages::INDEX,
        );
        let box_vb = vb(
            "box vertices",
            bytemuck::cast_slice(data.boxes.0),
            wgpu::BufferUsages::VERTEX,
        );
        let box_ib = vb(
            "box indices",
            bytemuck::cast_slice(data.boxes.1),
            wgpu::BufferUsages::INDEX,
        );

        let tex_entry = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let scene_layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("scene layout"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: true,
                        min_binding_size: wgpu::BufferSize::new(80),
                    },
                    count: None,
                },
                tex_entry(1),
                tex_entry(2),
                wgpu::BindGroupLayoutEntry {
                    binding: 3,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let terrain_view = terrain_tex.create_view(&Default::default());
        let atlas_view = atlas_tex.create_view(&Default::default());
        let scene_bind = dev.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene bind"),
            layout: &scene_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &camera_buf,
                        offset: 0,
                        size: wgpu::BufferSize::new(80),
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&terrain_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&atlas_view),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::Sampler(&sampler),
                },
            ],
        });
        let module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("scene.wgsl"),
            source: wgpu::ShaderSource::Wgsl(WGSL.into()),
        });
        let accum_module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("scene_accum.wgsl"),
            source: wgpu::ShaderSource::Wgsl(ACCUM_WGSL.into()),
        });
        let scene_pl = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("scene pipeline layout"),
            bind_group_layouts: &[Some(&scene_layout)],
            immediate_size: 0,
        });
        let vertex_attrs = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x2];
        let inst_attrs = wgpu::vertex_attr_array![3 => Float32x4, 4 => Float32x4, 5 => Float32x4, 6 => Float32x4, 7 => Float32x4, 8 => Float32x4];
        let colour_format = wgpu::TextureFormat::Rgba8Unorm;
        let scene_pipeline = dev.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("scene pipeline"),
            layout: Some(&scene_pl),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[
                    Some(wgpu::VertexBufferLayout {
                        array_stride: std::mem::size_of::<Vertex>() as u64,
                        step_mode: wgpu::VertexStepMode::Vertex,
                        attributes: &vertex_attrs,
                    }),
                    Some(wgpu::VertexBufferLayout {
                        array_stride: inst_size,
                        step_mode: wgpu::VertexStepMode::Instance,
                        attributes: &inst_attrs,
                    }),
                ],
            },
            primitive: wgpu::PrimitiveState {
                cull_mode: None,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: wgpu::TextureFormat::Depth32Float,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(colour_format.into())],
            }),
            multiview_mask: None,
            cache: None,
        });
        let tex_layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("scene accum layout"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }],
        });
        let accum_pl = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("scene accum pipeline layout"),
            bind_group_layouts: &[Some(&tex_layout)],
            immediate_size: 0,
        });
        let full = |entry: &str, format: wgpu::TextureFormat, blend: Option<wgpu::BlendState>| {
            dev.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(entry),
                layout: Some(&accum_pl),
                vertex: wgpu::VertexState {
                    module: &accum_module,
                    entry_point: Some("vs_full"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: Default::default(),
                depth_stencil: None,
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &accum_module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format,
                        blend,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let add = wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::Constant,
            dst_factor: wgpu::BlendFactor::One,
            operation: wgpu::BlendOperation::Add,
        };
        let accum_pipeline = full(
            "fs_accum",
            wgpu::TextureFormat::Rgba16Float,
            Some(wgpu::BlendState {
                color: add,
                alpha: add,
            }),
        );
        let resolve_pipeline = full("fs_resolve", colour_format, None);

        use wgpu::TextureUsages as U;
        let sub = ctx.texture(
            "scene sub-sample",
            (width, height),
            colour_format,
            U::RENDER_ATTACHMENT | U::TEXTURE_BINDING,
        );
        let depth = ctx.texture(
            "scene depth",
            (width, height),
            wgpu::TextureFormat::Depth32Float,
            U::RENDER_ATTACHMENT,
        );
        let accum = ctx.texture(
            "scene accumulator",
            (width, height),
            wgpu::TextureFormat::Rgba16Float,
            U::RENDER_ATTACHMENT | U::TEXTURE_BINDING,
        );
        let out_tex = ctx.texture(
            "scene output",
            (width, height),
            colour_format,
            U::RENDER_ATTACHMENT | U::COPY_SRC,
        );
        let sub_view = sub.create_view(&Default::default());
        let accum_view = accum.create_view(&Default::default());
        let tex_bind = |view: &wgpu::TextureView, label: &str| {
            dev.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout: &tex_layout,
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(view),
                }],
            })
        };
        let accum_bind = tex_bind(&sub_view, "scene accum bind");
        let resolve_bind = tex_bind(&accum_view, "scene resolve bind");
        let padded_row = (4 * width).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let readback = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("scene readback"),
            size: padded_row as u64 * height as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Renderer {
            ctx,
            width,
            height,
            samples,
            instances_per_slot: data.instances,
            scene_pipeline,
            accum_pipeline,
            resolve_pipeline,
            scene_bind,
            accum_bind,
            resolve_bind,
            camera_buf,
            instance_buf,
            terrain_vb,
            terrain_ib,
            terrain_count: data.terrain.1.len() as u32,
            box_vb,
            box_ib,
            box_count: data.boxes.1.len() as u32,
            sub_view,
            depth_view: depth.create_view(&Default::default()),
            accum_view,
            out_view: out_tex.create_view(&Default::default()),
            out_tex,
            readback,
            padded_row,
        })
    }

    /// Renders one frame as the average of `subs` (1 to `samples` of them), returning tightly
    /// packed RGBA8 rows, top row first.
    pub fn frame(&self, subs: &[SubSample], sun: [f32; 4]) -> Result<Vec<u8>> {
        if subs.is_empty() || subs.len() > self.samples as usize {
            return Err(Error::gpu(format!(
                "{} sub-samples given; the renderer takes 1 to {}",
                subs.len(),
                self.samples
            )));
        }
        let n = self.instances_per_slot as usize;
        let mut cams = vec![0u8; (SLOT * self.samples as u64) as usize];
        let mut insts = Vec::with_capacity(n * subs.len());
        for (k, sub) in subs.iter().enumerate() {
            let (clip, inst) = (&sub.clip, &sub.instances);
            if inst.len() != n {
                return Err(Error::gpu(format!(
                    "{} instances given; expected {n}",
                    inst.len()
                )));
            }
            let o = k * SLOT as usize;
            cams[o..o + 64].copy_from_slice(bytemuck::cast_slice(clip));
            cams[o + 64..o + 80].copy_from_slice(bytemuck::cast_slice(&sun));
            insts.extend_from_slice(inst);
        }
        let q = &self.ctx.queue;
        q.write_buffer(&self.camera_buf, 0, &cams);
        q.write_buffer(&self.instance_buf, 0, bytemuck::cast_slice(&insts));
        let mut enc = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("scene frame"),
            });
        let sky = wgpu::Color {
            r: 0.62,
            g: 0.74,
            b: 0.88,
            a: 1.0,
        };
        for (k, sub) in subs.iter().enumerate() {
            let k = k as u32;
            {
                let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("scene sub-sample"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &self.sub_view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(sky),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                        view: &self.depth_view,
                        depth_ops: Some(wgpu::Operations {
                            load: wgpu::LoadOp::Clear(1.0),
                            store: wgpu::StoreOp::Discard,
                        }),
                        stencil_ops: None,
                    }),
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                pass.set_pipeline(&self.scene_pipeline);
                pass.set_bind_group(0, &self.scene_bind, &[(k as u64 * SLOT) as u32]);
                let first = k * self.instances_per_slot;
                pass.set_vertex_buffer(1, self.instance_buf.slice(..));
                pass.set_vertex_buffer(0, self.terrain_vb.slice(..));
                pass.set_index_buffer(self.terrain_ib.slice(..), wgpu::IndexFormat::Uint32);
                for r in &sub.terrain {
                    if r.end <= self.terrain_count {
                        pass.draw_indexed(r.clone(), 0, first..first + 1);
                    }
                }
                if self.instances_per_slot > 1 {
                    pass.set_vertex_buffer(0, self.box_vb.slice(..));
                    pass.set_index_buffer(self.box_ib.slice(..), wgpu::IndexFormat::Uint32);
                    pass.draw_indexed(
                        0..self.box_count,
                        0,
                        first + 1..first + self.instances_per_slot,
                    );
                }
            }
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("scene accumulate"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.accum_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: if k == 0 {
                            wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT)
                        } else {
                            wgpu::LoadOp::Load
                        },
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.accum_pipeline);
            let w = 1.0 / subs.len() as f64;
            pass.set_blend_constant(wgpu::Color {
                r: w,
                g: w,
                b: w,
                a: w,
            });
            pass.set_bind_group(0, &self.accum_bind, &[]);
            pass.draw(0..3, 0..1);
        }
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("scene resolve"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &self.out_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&self.resolve_pipeline);
            pass.set_bind_group(0, &self.resolve_bind, &[]);
            pass.draw(0..3, 0..1);
        }
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &self.out_tex,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &self.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.padded_row),
                    rows_per_image: Some(self.height),
                },
            },
            wgpu::Extent3d {
                width: self.width,
                height: self.height,
                depth_or_array_layers: 1,
            },
        );
        q.submit([enc.finish()]);
        let padded = self.ctx.map_and_copy(&self.readback)?;
        let row = 4 * self.width as usize;
        let mut out = Vec::with_capacity(row * self.height as usize);
        for r in 0..self.height as usize {
            let o = r * self.padded_row as usize;
            out.extend_from_slice(&padded[o..o + row]);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    /// The scene's shaders pass naga's validation, as the product's kernels do
    /// (`keyframer::kernels::tests::every_shader_validates`).
    #[test]
    fn scene_shaders_validate() {
        for (name, src) in [("scene", super::WGSL), ("scene_accum", super::ACCUM_WGSL)] {
            if let Err(e) = keyframer::kernels::validate_wgsl(src) {
                panic!("{name}.wgsl: {e}");
            }
        }
    }
}
