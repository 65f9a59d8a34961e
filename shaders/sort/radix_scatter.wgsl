// Radix sort pass, step 2: every key goes to
//   scanned_counts[digit, block] + (keys of that digit in earlier threads of the block)
//   + (keys of that digit earlier in this thread),
// which keeps equal digits in input order (stable).
#import dispatch
#import radix

@group(0) @binding(0) var<uniform> sp: SortParams;
@group(0) @binding(1) var<storage, read> keys_in: array<vec4<u32>>;   // read 4 at a time
@group(0) @binding(2) var<storage, read> vals_in: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;   // scanned counts
@group(0) @binding(4) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> vals_out: array<u32>;

var<workgroup> table: array<u32, RADIX * SORT_THREADS>;      // [digit * SORT_THREADS + thread]
var<workgroup> chunk: array<array<u32, SORT_THREADS>, 2>;

@compute @workgroup_size(SORT_THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let block = linear_group(wid, nwg);
    let base = block * SORT_BLOCK + li * SORT_ITEMS;
    var local: array<u32, RADIX>;
    var keys: array<vec4<u32>, SORT_ITEMS / 4u>;      // this thread's SORT_ITEMS keys
    for (var i = 0u; i < SORT_ITEMS / 4u; i++) {
        if (base + 4u * i < sp.n) {
            keys[i] = keys_in[base / 4u + i];
        }
    }
    for (var i = 0u; i < SORT_ITEMS; i++) {
        if (base + i < sp.n) {
            local[(keys[i / 4u][i % 4u] >> sp.shift) & (RADIX - 1u)] += 1u;
        }
    }
    for (var d = 0u; d < RADIX; d++) {
        table[d * SORT_THREADS + li] = local[d];
    }
    workgroupBarrier();
    // Exclusive scan of table (digit-major): thread li scans entries [RADIX li, RADIX li + RADIX).
    var run = 0u;
    for (var i = 0u; i < RADIX; i++) {
        let x = table[li * RADIX + i];
        table[li * RADIX + i] = run;
        run += x;
    }
    chunk[0][li] = run;
    var src = 0u;
    workgroupBarrier();
    for (var off = 1u; off < SORT_THREADS; off = off * 2u) {
        var acc = chunk[src][li];
        if (li >= off) {
            acc += chunk[src][li - off];
        }
        chunk[1u - src][li] = acc;
        src = 1u - src;
        workgroupBarrier();
    }
    let chunk_excl = chunk[src][li] - run;
    for (var i = 0u; i < RADIX; i++) {
        table[li * RADIX + i] += chunk_excl;
    }
    workgroupBarrier();
    if (block >= sp.num_blocks) {
        return;
    }
    var seen: array<u32, RADIX>;
    for (var i = 0u; i < SORT_ITEMS; i += 4u) {
        if (base + i < sp.n) {
            let v4 = vals_in[(base + i) / 4u];
            for (var c = 0u; c < 4u; c++) {
                let idx = base + i + c;
                if (idx < sp.n) {
                    let key = keys[i / 4u][c];
                    let d = (key >> sp.shift) & (RADIX - 1u);
                    let dst = offsets[d * sp.num_blocks + block] + (table[d * SORT_THREADS + li] - table[d * SORT_THREADS])
                              + seen[d];
                    seen[d] += 1u;
                    keys_out[dst] = key;
                    vals_out[dst] = v4[c];
                }
            }
        }
    }
}
