// Occupancy-guided coarse edges, one invocation per ray (mipnerf-core's `occupancy.rs`,
// `OccupancyGrid::ray_segments`, and `sampling::sample_along_segments`):
// - the ray is clipped to the grid's cube (slab test) and walked cell by cell (Amanatides-Woo),
//   in the grid dilated to the cone's footprint where it leaves the cube; consecutive occupied
//   cells make one span;
// - the stratified edges (jittered in training, the same random stream as `sample.wgsl`'s
//   `stratified`) are laid over the spans joined end to end and mapped back into them; one span
//   is exactly `stratified` between its ends;
// - a ray that meets no occupied cell gets every edge at `near`: intervals of zero length, so it
//   renders the background (no opacity, distance `near`) and adds nothing to the gradient, as the
//   CPU's compacted path renders it.

struct Params {
    n_rays: u32,
    // Samples per ray; each ray has n_samples + 1 edges.
    n_samples: u32,
    lindisp: u32,
    randomized: u32,
    seed: u32,
    step: u32,
    // Cells along each axis.
    resolution: u32,
    // Half the side of the cube the grid covers (world units).
    bound: f32,
    // The side of one cell, 2 bound / resolution (computed once, in Rust).
    cell_size: f32,
    groups_x: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
// Two vec4 per ray: (origin, radius), (direction, lossmult).
@group(0) @binding(1) var<storage, read> rays: array<vec4<f32>>;
// (near, far) per ray.
@group(0) @binding(2) var<storage, read> bounds: array<f32>;
// The grid's layers as bits (cell i of layer k is bit i % 32 of word (k r^3 + i) / 32): layer 0
// the occupied cells, layer k the cells within k cells of an occupied one (`OccupancyGrid::
// packed_layers`).
@group(0) @binding(3) var<storage, read> bits: array<u32>;
@group(0) @binding(4) var<storage, read_write> t_out: array<f32>;
// The index of each ray in the step's batch (its random streams are drawn with it): 0.. for a
// whole batch, the chunk's or the compacted rays' own indices otherwise.
@group(0) @binding(5) var<storage, read> ray_ids: array<u32>;

// Most spans a ray keeps (the host refuses resolutions that could exceed it: at most
// 3 r / 2 + 1 spans for r cells along each axis).
const MAX_SPANS: u32 = 256u;
// The widest dilation of the grid (`occupancy::MAX_DILATION`).
const MAX_LAYER: f32 = 4.0;
// Stands for the CPU's infinity in the traversal (never reached by a real crossing).
const FAR_AWAY: f32 = 3.4e38;

var<private> spans: array<vec2<f32>, 256>;

fn ray_index(gid: vec3<u32>) -> u32 {
    return gid.y * (p.groups_x * WORKGROUP) + gid.x;
}

fn occupied(layer: u32, cell: vec3<i32>) -> bool {
    let r = p.resolution;
    let i = layer * r * r * r + (u32(cell.z) * r + u32(cell.y)) * r + u32(cell.x);
    return ((bits[i >> 5u] >> (i & 31u)) & 1u) != 0u;
}

// Appends [s, t] to the ray's spans (while there is room).
fn push_span(n: u32, s: f32, t: f32) -> u32 {
    if (n < MAX_SPANS) {
        spans[n] = vec2<f32>(s, t);
        return n + 1u;
    }
    return n;
}

// `OccupancyGrid::ray_segments`: the ray's occupied spans into `spans`, their count returned.
fn ray_segments(origin: vec3<f32>, direction: vec3<f32>, radius: f32, near: f32, far: f32) -> u32 {
    let b = p.bound;
    let r = i32(p.resolution);
    let h = p.cell_size;
    var t0 = near;
    var t1 = far;
    for (var a = 0; a < 3; a = a + 1) {
        let o = origin[a];
        let d = direction[a];
        if (d == 0.0) {
            if (o < -b || o > b) {
                return 0u;
            }
            continue;
        }
        let ta = (-b - o) / d;
        let tb = (b - o) / d;
        t0 = max(t0, min(ta, tb));
        t1 = min(t1, max(ta, tb));
    }
    if (!(t0 < t1)) {
        return 0u;
    }
    let reach = 2.0 * radius * abs(t1) / h;
    let k = ceil(reach);
    var layer = 0u;
    if (k >= 1.0) {
        layer = u32(min(k, MAX_LAYER));
    }
    let pos = origin + direction * t0;
    var cell = vec3<i32>(0, 0, 0);
    var step = vec3<i32>(0, 0, 0);
    var t_max = vec3<f32>(FAR_AWAY, FAR_AWAY, FAR_AWAY);
    var t_delta = vec3<f32>(FAR_AWAY, FAR_AWAY, FAR_AWAY);
    for (var a = 0; a < 3; a = a + 1) {
        cell[a] = clamp(i32(floor((pos[a] + b) / h)), 0, r - 1);
        let d = direction[a];
        if (d > 0.0) {
            step[a] = 1;
            t_max[a] = (-b + f32(cell[a] + 1) * h - origin[a]) / d;
            t_delta[a] = h / d;
        } else if (d < 0.0) {
            step[a] = -1;
            t_max[a] = (-b + f32(cell[a]) * h - origin[a]) / d;
            t_delta[a] = -h / d;
        }
    }
    var t = t0;
    var open = false;
    var s = 0.0;
    var n = 0u;
    while (t < t1) {
        var a = 2;
        if (t_max[0] <= t_max[1] && t_max[0] <= t_max[2]) {
            a = 0;
        } else if (t_max[1] <= t_max[2]) {
            a = 1;
        }
        let t_next = max(min(t_max[a], t1), t);
        let occ = occupied(layer, cell);
        if (occ && !open) {
            open = true;
            s = t;
        } else if (!occ && open) {
            if (t > s) {
                n = push_span(n, s, t);
            }
            open = false;
        }
        t = t_next;
        if (step[a] == 0) {
            // Only when no axis moves (a zero direction): t_next was t1.
            break;
        }
        cell[a] = cell[a] + step[a];
        t_max[a] = t_max[a] + t_delta[a];
        if (cell[a] < 0 || cell[a] >= r) {
            break;
        }
    }
    if (open && t > s) {
        n = push_span(n, s, t);
    }
    return n;
}

// `sampling::sample_along_rays` into the ray's edges at `base`.
fn sample_along(base: u32, near: f32, far: f32, lindisp: bool, key: u32) {
    let n = p.n_samples;
    for (var i = 0u; i <= n; i = i + 1u) {
        t_out[base + i] = stratified_edge(i, n, near, far, lindisp, p.randomized != 0u, key);
    }
}

@compute @workgroup_size(WORKGROUP)
fn sample_occupied(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = ray_index(gid);
    if (r >= p.n_rays) {
        return;
    }
    let origin = rays[2u * r].xyz;
    let radius = rays[2u * r].w;
    let direction = rays[2u * r + 1u].xyz;
    let near = bounds[2u * r];
    let far = bounds[2u * r + 1u];
    let n = p.n_samples;
    let base = r * (n + 1u);
    let n_spans = ray_segments(origin, direction, radius, near, far);
    if (n_spans == 0u) {
        for (var i = 0u; i <= n; i = i + 1u) {
            t_out[base + i] = near;
        }
        return;
    }
    let key = stream_key(p.seed, p.step, STREAM_SAMPLE_JITTER, ray_ids[r]);
    if (n_spans == 1u) {
        sample_along(base, spans[0].x, spans[0].y, p.lindisp != 0u, key);
        return;
    }
    var total = 0.0;
    for (var k = 0u; k < n_spans; k = k + 1u) {
        total = total + (spans[k].y - spans[k].x);
    }
    sample_along(base, 0.0, total, false, key);
    // Each joined coordinate back into its span; the edges are sorted, so walk the spans once.
    var k = 0u;
    var start = 0.0;
    let last = n_spans - 1u;
    for (var i = 0u; i <= n; i = i + 1u) {
        let t = t_out[base + i];
        while (k < last && t > start + (spans[k].y - spans[k].x)) {
            start = start + (spans[k].y - spans[k].x);
            k = k + 1u;
        }
        t_out[base + i] = clamp(spans[k].x + (t - start), spans[k].x, spans[k].y);
    }
}
