// Small passes around the MLP's matrix products, one entry point each:
// - col_sums: out[col] (+)= sum over rows of g[row, col] (the bias gradient), one invocation per
//   column summing rows in order, so the result is deterministic;
// - col_sums_partial: the first of two passes for tall matrices: per block of 256 rows and column,
//   the block's sum in row order (col_sums then adds the blocks in order), so that a matrix of
//   a million rows is summed by many invocations, not one per column;
// - pack_heads / unpack_heads_add: the density and bottleneck layers' kernels and biases,
//   (T + 1) x 1 and (T + 1) x W in the flat parameters, as one (T + 1) x (W + 1) matrix
//   [density | bottleneck] (so that both heads are one product), and its gradient added back;
// - group_sums: out[r, :] = sum over i < count of x[r * count + i, :] in order (a ray's samples'
//   gradients, for the view-direction weights, which multiply once per ray).

// The uniform block `Params` is declared from the Rust struct `AuxParams` (kernels/mlp_aux.rs).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

fn flat_id(gid: vec3<u32>) -> u32 {
    return gid.y * (p.groups_x * WORKGROUP) + gid.x;
}

// x = gradient [rows x cols]; out = bias gradient [cols].
@compute @workgroup_size(WORKGROUP)
fn col_sums(@builtin(global_invocation_id) gid: vec3<u32>) {
    let col = flat_id(gid);
    if (col >= p.cols) {
        return;
    }
    var s = 0.0;
    for (var r = 0u; r < p.rows; r = r + 1u) {
        s = s + x[p.x_off + r * p.cols + col];
    }
    if (p.accumulate != 0u) {
        s = out[p.out_off + col] + s;
    }
    out[p.out_off + col] = s;
}

// x = gradient [rows x cols]; out = partial sums [ceil(rows / 256) x cols] from out_off.
@compute @workgroup_size(WORKGROUP)
fn col_sums_partial(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_id(gid);
    let blocks = (p.rows + MLP_BLOCK_ROWS - 1u) / MLP_BLOCK_ROWS;
    if (i >= blocks * p.cols) {
        return;
    }
    let col = i % p.cols;
    let r0 = (i / p.cols) * MLP_BLOCK_ROWS;
    let r1 = min(r0 + MLP_BLOCK_ROWS, p.rows);
    var s = 0.0;
    for (var r = r0; r < r1; r = r + 1u) {
        s = s + x[p.x_off + r * p.cols + col];
    }
    out[p.out_off + i] = s;
}

// x = per-sample rows [rows * count x cols]; out = per-group sums [rows x cols] from out_off.
@compute @workgroup_size(WORKGROUP)
fn group_sums(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_id(gid);
    if (i >= p.rows * p.cols) {
        return;
    }
    let col = i % p.cols;
    let r = i / p.cols;
    var s = 0.0;
    for (var j = 0u; j < p.count; j = j + 1u) {
        s = s + x[p.x_off + (r * p.count + j) * p.cols + col];
    }
    out[p.out_off + i] = s;
}

// x = parameters; out = the packed heads from out_off: rows x (cols + 1), column 0 from the
// density layer at x_off ((rows) x 1), columns 1.. from the bottleneck layer at y_off (rows x cols).
@compute @workgroup_size(WORKGROUP)
fn pack_heads(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_id(gid);
    let w = p.cols + 1u;
    if (i >= p.rows * w) {
        return;
    }
    let r = i / w;
    let c = i % w;
    var v = 0.0;
    if (c == 0u) {
        v = x[p.x_off + r];
    } else {
        v = x[p.y_off + r * p.cols + c - 1u];
    }
    out[p.out_off + i] = v;
}

// x = the packed heads' gradient from x_off (rows x (cols + 1)); out = gradients: column 0 added
// to the density layer's at out_off, columns 1.. to the bottleneck layer's at y_off.
@compute @workgroup_size(WORKGROUP)
fn unpack_heads_add(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = flat_id(gid);
    let w = p.cols + 1u;
    if (i >= p.rows * w) {
        return;
    }
    let r = i / w;
    let c = i % w;
    var dst = p.out_off + r;
    if (c != 0u) {
        dst = p.y_off + r * p.cols + c - 1u;
    }
    out[dst] = out[dst] + x[p.x_off + i];
}
