// Ray batches made on the device from images and cameras that live there: mipnerf-core's
// `Dataset::sample_batch` (training: pixels drawn uniformly, with replacement, from every pixel of
// every view with the CPU's counter-based random numbers) and a view's rays in raster order
// (rendering, chunk by chunk).
//
// In NDC (forward-facing scenes, `ndc_fx > 0`) each ray is mapped as mipnerf-core's `ndc_ray`
// does (the official `convert_to_ndc`, near plane at 1), in f32 as the official code: the radius
// comes from the spacing of neighbouring NDC origins (last row and column reuse the ones before),
// the view direction is the world direction, unnormalised, and lossmult is 1.
//
// A pinhole ray's direction is linear in the pixel coordinates, so each view is uploaded as the
// direction through pixel (0, 0) (with the pixel-centre offset) and its steps along x and y, all
// computed in f64 on the host and rounded once. The cone radius of a linear camera is the same
// for every pixel (the spacing of neighbouring directions), so it is uploaded per view too; this
// includes the official last-row rule, which reuses the previous row's (equal) spacing.
//
// Entry points:
// - `make_rays`: one invocation per ray; writes the ray, its bounds, view direction and target.
// - `batch_norm`: one workgroup; writes 3 * sum(lossmult) over the batch's pixels (3 * pixels
//   without the area loss), the denominator of the loss, in a fixed order (deterministic).

// The uniform block `Params` is declared from the Rust struct `BatchParams` (kernels/batch.rs).

// `View` is declared from the Rust struct `GpuView` (kernels/batch.rs).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> views: array<View>;
// Cumulative pixel counts: view v holds global pixels offsets[v]..offsets[v + 1].
@group(0) @binding(2) var<storage, read> offsets: array<u32>;
// The pixels, split over four buffers so that a dataset may exceed one binding's size limit.
@group(0) @binding(3) var<storage, read> pixels0: array<u32>;
@group(0) @binding(4) var<storage, read> pixels1: array<u32>;
@group(0) @binding(5) var<storage, read> pixels2: array<u32>;
@group(0) @binding(6) var<storage, read> pixels3: array<u32>;
// Two vec4 per ray: (origin.xyz, radius), (direction.xyz, lossmult).
@group(0) @binding(7) var<storage, read_write> rays: array<vec4<f32>>;
// (near, far) per ray.
@group(0) @binding(8) var<storage, read_write> bounds: array<f32>;
// Normalised direction per ray, 3 floats.
@group(0) @binding(9) var<storage, read_write> viewdirs: array<f32>;
// vec4 per ray: (r, g, b, 0).
@group(0) @binding(10) var<storage, read_write> targets: array<vec4<f32>>;
// [0]: 3 * sum(lossmult) over the batch.
@group(0) @binding(11) var<storage, read_write> norm: array<f32>;

// (hi * 2^32 + lo) mod m for 0 < m, bit by bit without overflow: the CPU's `u64 % total`.
fn mod64(hi: u32, lo: u32, m: u32) -> u32 {
    var r = 0u;
    for (var b = 0u; b < 64u; b = b + 1u) {
        let word = select(lo, hi, b < 32u);
        let bit = (word >> (31u - (b & 31u))) & 1u;
        // r = 2r mod m: 2r >= m exactly when r >= m - r.
        let room = m - r;
        r = select(r + r, r - room, r >= room);
        if (bit == 1u) {
            r = select(r + 1u, 0u, r + 1u == m);
        }
    }
    return r;
}

// The world direction through pixel (x, y) of view v.
fn world_dir(v: View, x: u32, y: u32) -> vec3<f32> {
    return v.dir0.xyz + f32(x) * v.step_x.xyz + f32(y) * v.step_y.xyz;
}

struct NdcRay {
    origin: vec3<f32>,
    dir: vec3<f32>,
}

// The official `convert_to_ndc` with the near plane at 1.
fn ndc_of(o: vec3<f32>, d: vec3<f32>) -> NdcRay {
    let t = -(1.0 + o.z) / d.z;
    let on = o + t * d;
    var r: NdcRay;
    r.origin = vec3<f32>(-p.ndc_fx * (on.x / on.z), -p.ndc_fy * (on.y / on.z), 1.0 + 2.0 / on.z);
    r.dir = vec3<f32>(-p.ndc_fx * (d.x / d.z - on.x / on.z), -p.ndc_fy * (d.y / d.z - on.y / on.z), -2.0 / on.z);
    return r;
}

// The index whose spacing to the next one a pixel uses: its own, or for the last, the one the
// official code takes (n - 3, at least 0).
fn pick(i: u32, n: u32) -> u32 {
    if (i + 1u < n) {
        return i;
    }
    return select(0u, n - 3u, n >= 3u);
}

fn fetch(slot: u32, i: u32) -> u32 {
    switch slot {
        case 0u: { return pixels0[i]; }
        case 1u: { return pixels1[i]; }
        case 2u: { return pixels2[i]; }
        default: { return pixels3[i]; }
    }
}

@compute @workgroup_size(WORKGROUP)
fn make_rays(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    if (i >= p.n_rays) {
        return;
    }
    let k = p.supersample;
    let pix = i / (k * k);
    let sub = i % (k * k);
    var g: u32;
    if (p.sequential != 0u) {
        // Rays past the last pixel (the tail of the last chunk) repeat it.
        g = min(p.first_pixel + pix, p.total_pixels - 1u);
    } else {
        let hi = stream_bits(p.key, 2u * pix);
        let lo = stream_bits(p.key, 2u * pix + 1u);
        g = mod64(hi, lo, p.total_pixels);
    }
    // The last view whose first pixel is at or before g.
    var lo_v = 0u;
    var hi_v = p.n_views;
    while (hi_v - lo_v > 1u) {
        let mid = (lo_v + hi_v) / 2u;
        if (offsets[mid] <= g) {
            lo_v = mid;
        } else {
            hi_v = mid;
        }
    }
    let v = views[lo_v];
    let local = g - offsets[lo_v];
    let x = local % v.size.x;
    let y = local / v.size.x;
    let dir = world_dir(v, x, y);
    bounds[2u * i] = v.step_x.w;
    bounds[2u * i + 1u] = v.step_y.w;
    var vd = dir / sqrt(dot(dir, dir));
    if (p.ndc_fx > 0.0) {
        let o = v.origin.xyz;
        let r = ndc_of(o, dir);
        let w = v.size.x;
        let h = v.size.y;
        var dy = 0.0;
        if (h > 1u) {
            let py = pick(y, h);
            dy = length(ndc_of(o, world_dir(v, x, py)).origin - ndc_of(o, world_dir(v, x, py + 1u)).origin);
        }
        var dx = 0.0;
        if (w > 1u) {
            let px = pick(x, w);
            dx = length(ndc_of(o, world_dir(v, px, y)).origin - ndc_of(o, world_dir(v, px + 1u, y)).origin);
        }
        var spacing = dx;
        if (h > 1u && w > 1u) {
            spacing = 0.5 * (dx + dy);
        } else if (h > 1u) {
            spacing = dy;
        }
        rays[2u * i] = vec4<f32>(r.origin, spacing * 0.57735026);
        rays[2u * i + 1u] = vec4<f32>(r.dir, 1.0);
        vd = dir;
    } else if (k > 1u) {
        // mipnerf-core's `push_camera_rays`: through (x + (sx + 0.5) / k, y + (sy + 0.5) / k).
        let fk = f32(k);
        let ox = (f32(sub % k) + 0.5) / fk - p.centre_offset;
        let oy = (f32(sub / k) + 0.5) / fk - p.centre_offset;
        let sdir = dir + ox * v.step_x.xyz + oy * v.step_y.xyz;
        rays[2u * i] = vec4<f32>(v.origin.xyz, v.dir0.w / fk);
        rays[2u * i + 1u] = vec4<f32>(sdir, v.origin.w);
        vd = sdir / sqrt(dot(sdir, sdir));
    } else {
        rays[2u * i] = vec4<f32>(v.origin.xyz, v.dir0.w);
        rays[2u * i + 1u] = vec4<f32>(dir, v.origin.w);
    }
    viewdirs[3u * i] = vd.x;
    viewdirs[3u * i + 1u] = vd.y;
    viewdirs[3u * i + 2u] = vd.z;
    var rgba = vec4<f32>(0.0);
    if (p.pixel_format == PIXEL_FORMAT_RGBA8) {
        let w = fetch(v.size.z, v.size.w + local);
        rgba = vec4<f32>(f32(w & 255u), f32((w >> 8u) & 255u), f32((w >> 16u) & 255u), f32(w >> 24u)) / 255.0;
    } else if (p.pixel_format == PIXEL_FORMAT_F32) {
        let k = v.size.w + 4u * local;
        rgba = vec4<f32>(
            bitcast<f32>(fetch(v.size.z, k)),
            bitcast<f32>(fetch(v.size.z, k + 1u)),
            bitcast<f32>(fetch(v.size.z, k + 2u)),
            bitcast<f32>(fetch(v.size.z, k + 3u)),
        );
    }
    var rgb = rgba.xyz;
    if (p.background == BACKGROUND_WHITE) {
        rgb = rgb * rgba.w + (1.0 - rgba.w);
    } else if (p.background == BACKGROUND_RANDOM) {
        rgb = rgb * rgba.w + random_background(p.seed, p.step, pix) * (1.0 - rgba.w);
    }
    targets[i] = vec4<f32>(rgb, 0.0);
}

const NORM_THREADS: u32 = REDUCE_WORKGROUP;
var<workgroup> partial: array<f32, REDUCE_WORKGROUP>;

@compute @workgroup_size(REDUCE_WORKGROUP)
fn batch_norm(@builtin(local_invocation_index) t: u32) {
    var s = 0.0;
    for (var r = t; r < p.n_rays; r = r + NORM_THREADS) {
        s = s + select(1.0, rays[2u * r + 1u].w, p.area_loss != 0u);
    }
    partial[t] = s;
    workgroupBarrier();
    for (var half = NORM_THREADS / 2u; half > 0u; half = half / 2u) {
        if (t < half) {
            partial[t] = partial[t] + partial[t + half];
        }
        workgroupBarrier();
    }
    if (t == 0u) {
        // Every pixel's k x k rays carry its lossmult: the sum over pixels.
        norm[0] = 3.0 * partial[0] / f32(p.supersample * p.supersample);
    }
}
