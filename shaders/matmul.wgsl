// C[m x n] (=|+=) A[m x k] · B[k x n], then optionally + bias[col] and ReLU.
//
// Operands live anywhere in their buffers (element offsets), stored row-major, each optionally
// transposed (stored n x k / k x m). 16 x 16 output tiles per workgroup, staged through workgroup
// memory in 16-wide slices of k; every output element sums over k in one fixed order, so results
// are deterministic (no atomics). The bias, if any, is read from B's buffer (the parameters).

struct Params {
    m: u32,
    k: u32,
    n: u32,
    // bit 0: A transposed; bit 1: B transposed; bit 2: accumulate into C; bit 3: add bias;
    // bit 4: ReLU after the bias.
    flags: u32,
    a_off: u32,
    b_off: u32,
    c_off: u32,
    bias_off: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> c: array<f32>;

const TILE: u32 = 16u;
var<workgroup> tile_a: array<array<f32, 16>, 16>;
var<workgroup> tile_b: array<array<f32, 16>, 16>;

fn load_a(row: u32, col: u32) -> f32 {
    if (row >= p.m || col >= p.k) {
        return 0.0;
    }
    if ((p.flags & 1u) != 0u) {
        return a[p.a_off + col * p.m + row];
    }
    return a[p.a_off + row * p.k + col];
}

fn load_b(row: u32, col: u32) -> f32 {
    if (row >= p.k || col >= p.n) {
        return 0.0;
    }
    if ((p.flags & 2u) != 0u) {
        return b[p.b_off + col * p.k + row];
    }
    return b[p.b_off + row * p.n + col];
}

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let row = wg.y * TILE + lid.y;
    let col = wg.x * TILE + lid.x;
    var acc = 0.0;
    let n_tiles = (p.k + TILE - 1u) / TILE;
    for (var t = 0u; t < n_tiles; t = t + 1u) {
        tile_a[lid.y][lid.x] = load_a(row, t * TILE + lid.x);
        tile_b[lid.y][lid.x] = load_b(t * TILE + lid.y, col);
        workgroupBarrier();
        for (var i = 0u; i < TILE; i = i + 1u) {
            acc = acc + tile_a[lid.y][i] * tile_b[i][lid.x];
        }
        workgroupBarrier();
    }
    if (row >= p.m || col >= p.n) {
        return;
    }
    let idx = p.c_off + row * p.n + col;
    if ((p.flags & 4u) != 0u) {
        acc = c[idx] + acc;
    }
    if ((p.flags & 8u) != 0u) {
        acc = acc + b[p.bias_off + col];
    }
    if ((p.flags & 16u) != 0u) {
        acc = max(acc, 0.0);
    }
    c[idx] = acc;
}
