//! One type per WGSL kernel, each owning its pipeline and bind-group layout, and the helpers they
//! share.

pub mod adam;
pub mod batch;
pub mod cast_ipe;
pub mod matmul;
pub mod mlp_aux;
pub mod render;
pub mod sample;
pub mod view_enc;

use crate::{GpuContext, GpuError};

/// Every WGSL source of the crate, by file name, for validation and `mipnerf info`.
pub const ALL_SOURCES: &[(&str, &str)] = &[
    ("cast_ipe.wgsl", cast_ipe::SOURCE),
    ("matmul.wgsl", matmul::SOURCE),
    ("mlp_aux.wgsl", mlp_aux::SOURCE),
    ("render.wgsl", render::SOURCE),
    ("adam.wgsl", adam::SOURCE),
    ("sample.wgsl", sample::SOURCE),
    ("view_enc.wgsl", view_enc::SOURCE),
    ("batch.wgsl", batch::SOURCE),
];

/// Most workgroups a dispatch may have along one dimension.
pub const MAX_GROUPS_PER_DIM: u32 = 65_535;

/// A 2-D grid of workgroups covering `n_items` invocations of `workgroup` each: `(x, y)` with
/// `x <= 65535`. Kernels flatten it as `gid.y * (x * workgroup) + gid.x`.
///
/// # Errors
/// [`GpuError::InvalidInput`] when even a 65535 x 65535 grid is too small.
pub fn dispatch_grid(n_items: u64, workgroup: u32) -> Result<(u32, u32), GpuError> {
    let groups = n_items.div_ceil(u64::from(workgroup)).max(1);
    let gx = groups.min(u64::from(MAX_GROUPS_PER_DIM));
    let gy = groups.div_ceil(gx);
    if gy > u64::from(MAX_GROUPS_PER_DIM) {
        return Err(GpuError::InvalidInput(format!("{n_items} invocations exceed one dispatch")));
    }
    Ok((gx as u32, gy as u32))
}

/// A bind-group layout of one uniform block at binding 0 followed by storage buffers at bindings
/// 1.., read-only where `read_only[i]` is true.
#[must_use]
pub fn storage_layout(ctx: &GpuContext, name: &str, read_only: &[bool]) -> wgpu::BindGroupLayout {
    let mut entries = vec![wgpu::BindGroupLayoutEntry {
        binding: 0,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }];
    for (i, &ro) in read_only.iter().enumerate() {
        entries.push(wgpu::BindGroupLayoutEntry {
            binding: i as u32 + 1,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: ro },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        });
    }
    ctx.device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(&format!("{name} layout")),
        entries: &entries,
    })
}

/// The `main` pipeline of `source` and its layout (a uniform block, then storage buffers,
/// read-only where `read_only[i]`), checked by the device: what every single-entry kernel owns.
///
/// # Errors
/// [`GpuError::Validation`] if the device rejects the shader or pipeline.
pub fn build(
    ctx: &GpuContext,
    name: &str,
    source: &str,
    read_only: &[bool],
) -> Result<(wgpu::ComputePipeline, wgpu::BindGroupLayout), GpuError> {
    let ([pipeline], layout) = build_entries(ctx, name, source, read_only, ["main"])?;
    Ok((pipeline, layout))
}

/// The pipelines of the entry points `entries` of `source`, sharing one layout (a uniform block,
/// then storage buffers, read-only where `read_only[i]`), checked by the device: what every
/// kernel type owns.
///
/// # Errors
/// [`GpuError::Validation`] if the device rejects the shader or a pipeline.
pub fn build_entries<const N: usize>(
    ctx: &GpuContext,
    name: &str,
    source: &str,
    read_only: &[bool],
    entries: [&str; N],
) -> Result<([wgpu::ComputePipeline; N], wgpu::BindGroupLayout), GpuError> {
    let layout = storage_layout(ctx, name, read_only);
    let pipelines = entries.map(|e| compute_pipeline_entry(ctx, &format!("{name} {e}"), source, e, &layout));
    ctx.check()?;
    Ok((pipelines, layout))
}

/// A labelled compute pipeline for entry point `entry` of `source`.
#[must_use]
pub fn compute_pipeline_entry(
    ctx: &GpuContext,
    name: &str,
    source: &str,
    entry: &str,
    layout: &wgpu::BindGroupLayout,
) -> wgpu::ComputePipeline {
    let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pl = ctx.device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(&format!("{name} pipeline layout")),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(&format!("{name} pipeline")),
        layout: Some(&pl),
        module: &module,
        entry_point: Some(entry),
        compilation_options: wgpu::PipelineCompilationOptions::default(),
        cache: None,
    })
}

/// Records one dispatch of `pipeline` with a fresh uniform block `params` at binding 0 and the
/// storage `buffers` (whole buffers) at bindings 1.., into `enc`.
pub fn dispatch<P: bytemuck::Pod>(
    ctx: &GpuContext,
    enc: &mut wgpu::CommandEncoder,
    name: &str,
    pipeline: &wgpu::ComputePipeline,
    layout: &wgpu::BindGroupLayout,
    params: &P,
    buffers: &[&wgpu::Buffer],
    groups: (u32, u32, u32),
) {
    let uniform = ctx.uniform_buffer(&format!("{name} params"), params);
    let mut entries = vec![wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() }];
    for (i, b) in buffers.iter().enumerate() {
        entries.push(wgpu::BindGroupEntry { binding: i as u32 + 1, resource: b.as_entire_binding() });
    }
    let bind =
        ctx.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some(name), layout, entries: &entries });
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(name), timestamp_writes: None });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &bind, &[]);
    pass.dispatch_workgroups(groups.0, groups.1, groups.2);
}
