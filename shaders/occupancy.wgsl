// Occupancy-guided coarse edges, one invocation per ray (mipnerf-core's `occupancy.rs`,
// `OccupancyGrid::ray_segments`, and `sampling::sample_along_segments`):
// - the ray is clipped to the grid's cube (slab test) and walked cell by cell (Amanatides-Woo),
//   in the grid dilated to the cone's footprint where it leaves the cube; consecutive occupied
//   cells make one span;
// - one span is exactly `stratified` between its ends; several get an edge at each end, so no
//   interval straddles an empty gap: each gap is one interval, the others are shared out among
//   the spans by length and stratified inside each (jittered in training by the same random
//   stream as `sample.wgsl`'s `stratified`), the spans with the narrowest gaps joined first when
//   there are too many;
// - a ray that meets no occupied cell gets every edge at `near`: intervals of zero length, so it
//   renders the background (no opacity, distance `near`) and adds nothing to the gradient, as the
//   CPU's compacted path renders it.
// A grid over an unbounded scene's contracted space (`contracted` 1, `OccupancyGrid::
// contracted_ray_segments`) is walked in even steps of the normalised distance s instead, each
// step looked up at its point's contraction; with `spacing` 2 the spans are shared out in s (as
// `sample.wgsl` spaces an unbounded ray's edges), mapped back to t, the ray's first and last
// edge kept at its spans' ends.

// The uniform block `Params` is declared from the Rust struct `OccupancyParams` (kernels/occupancy.rs).

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
// `occupancy::CONTRACTED_STEPS_PER_CELL`: steps of the contracted walk per cell of the grid.
const CONTRACTED_STEPS_PER_CELL: u32 = 2u;
const SPACING_DISPARITY: u32 = 1u;
const SPACING_UNBOUNDED: u32 = 2u;

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

// mipnerf-core's `contract::contract`: the identity inside the unit ball, (2 - 1/|x|) x/|x|
// outside it.
fn contract_point(x: vec3<f32>) -> vec3<f32> {
    let r2 = dot(x, x);
    if (r2 <= 1.0) {
        return x;
    }
    let r = sqrt(r2);
    return x * ((2.0 - 1.0 / r) / r);
}

// Edge k of the contracted walk's n steps of s from s0 by ds: the ray's own near and far at
// either end.
fn walk_edge(k: u32, n: u32, s0: f32, ds: f32, near: f32, far: f32) -> f32 {
    if (k == 0u) {
        return near;
    }
    if (k == n) {
        return far;
    }
    return s_to_ray_distance(s0 + f32(k) * ds);
}

// `OccupancyGrid::contracted_ray_segments`: from near to far in `CONTRACTED_STEPS_PER_CELL`
// steps of s per cell, each step occupied when the cell of its middle's contraction is (in the
// layer dilated to the cone's width there, its world width times the contraction's sideways
// scale); consecutive occupied steps make one span.
fn contracted_ray_segments(origin: vec3<f32>, direction: vec3<f32>, radius: f32, near: f32, far: f32) -> u32 {
    let s0 = ray_distance_to_s(near);
    let s1 = ray_distance_to_s(far);
    if (!(s0 < s1)) {
        return 0u;
    }
    let r = p.resolution;
    let h = p.cell_size;
    let b = p.bound;
    let steps = CONTRACTED_STEPS_PER_CELL * r;
    let ds = (s1 - s0) / f32(steps);
    var open = false;
    var start = 0.0;
    var n = 0u;
    for (var k = 0u; k < steps; k = k + 1u) {
        let t = s_to_ray_distance(s0 + (f32(k) + 0.5) * ds);
        let x = origin + direction * t;
        let dist = length(x);
        var across = 1.0;
        if (dist > 1.0) {
            across = (2.0 - 1.0 / dist) / dist;
        }
        let reach = ceil(2.0 * radius * t * across / h);
        var layer = 0u;
        if (reach >= 1.0) {
            layer = u32(min(reach, MAX_LAYER));
        }
        let cell = (contract_point(x) + b) / h;
        let inside = min(min(cell.x, cell.y), cell.z) >= 0.0 && max(max(cell.x, cell.y), cell.z) < f32(r);
        let occ = inside && occupied(layer, vec3<i32>(cell));
        if (occ && !open) {
            open = true;
            start = walk_edge(k, steps, s0, ds, near, far);
        } else if (!occ && open) {
            n = push_span(n, start, walk_edge(k, steps, s0, ds, near, far));
            open = false;
        }
    }
    if (open) {
        n = push_span(n, start, far);
    }
    return n;
}

// `OccupancyGrid::ray_segments`: the ray's occupied spans into `spans`, their count returned.
fn ray_segments(origin: vec3<f32>, direction: vec3<f32>, radius: f32, near: f32, far: f32) -> u32 {
    if (p.contracted != 0u) {
        return contracted_ray_segments(origin, direction, radius, near, far);
    }
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
    // An unbounded ray's spans are shared out in s, its edges mapped back to t at the end.
    let unbounded = p.spacing == SPACING_UNBOUNDED;
    let t_first = spans[0].x;
    let t_last = spans[n_spans - 1u].y;
    if (unbounded) {
        for (var k = 0u; k < n_spans; k = k + 1u) {
            spans[k] = vec2<f32>(ray_distance_to_s(spans[k].x), ray_distance_to_s(spans[k].y));
        }
    }
    edges_in_spans(base, n_spans, key);
    if (unbounded) {
        for (var i = 0u; i <= n; i = i + 1u) {
            t_out[base + i] = s_to_ray_distance(t_out[base + i]);
        }
        t_out[base] = t_first;
        t_out[base + n] = t_last;
    }
}

// `sampling::sample_along_segments` of the ray's `n_spans` spans into its edges at `base`.
fn edges_in_spans(base: u32, n_spans: u32, key: u32) {
    let n = p.n_samples;
    if (n_spans == 1u) {
        sample_along(base, spans[0].x, spans[0].y, p.spacing == SPACING_DISPARITY, key);
        return;
    }
    // `sampling::join_narrowest_gaps`: the spans with the narrowest gaps joined first until
    // every span has an interval and every gap one.
    var ns = n_spans;
    while (ns > 1u && 2u * ns - 1u > n) {
        var k = 0u;
        for (var i = 1u; i < ns - 1u; i = i + 1u) {
            if (spans[i + 1u].x - spans[i].y < spans[k + 1u].x - spans[k].y) {
                k = i;
            }
        }
        spans[k].y = spans[k + 1u].y;
        for (var i = k + 1u; i < ns - 1u; i = i + 1u) {
            spans[i] = spans[i + 1u];
        }
        ns = ns - 1u;
    }
    if (ns == 1u) {
        sample_along(base, spans[0].x, spans[0].y, false, key);
        return;
    }
    // `sampling::sample_along_segments`: an edge at each end of every span; each gap one
    // interval; the spare intervals shared out by length (`sampling::span_intervals`).
    var total = 0.0;
    for (var k = 0u; k < ns; k = k + 1u) {
        total = total + (spans[k].y - spans[k].x);
    }
    let spare = n - (2u * ns - 1u);
    var cum = 0.0;
    var prev_share = 0u;
    var e = 0u;
    for (var k = 0u; k < ns; k = k + 1u) {
        cum = cum + (spans[k].y - spans[k].x);
        var share = spare;
        if (k + 1u < ns) {
            share = min(u32(floor(f32(spare) * (cum / total) + 0.5)), spare);
        }
        let m = 1u + share - prev_share;
        prev_share = share;
        let t0 = spans[k].x;
        let t1 = spans[k].y;
        for (var j = 0u; j <= m; j = j + 1u) {
            let base_t = span_edge(t0, t1, j, m);
            var t = base_t;
            if (p.randomized != 0u && j > 0u && j < m) {
                let lower = 0.5 * (span_edge(t0, t1, j - 1u, m) + base_t);
                let upper = 0.5 * (span_edge(t0, t1, j + 1u, m) + base_t);
                t = lower + (upper - lower) * uniform01(key, e + j);
            }
            t_out[base + e + j] = t;
        }
        e = e + m + 1u;
    }
}

// Edge `j` of `m` intervals evenly spaced over [t0, t1].
fn span_edge(t0: f32, t1: f32, j: u32, m: u32) -> f32 {
    let s = f32(j) / f32(m);
    return t0 * (1.0 - s) + t1 * s;
}
