// Binning works on (triangle, tile row) items so that no invocation loops over more
// than one row of tiles. Items are numbered in depth-rank order, rows top to bottom:
// item q belongs to the rank j with row_offsets[j] <= q < row_offsets[j + 1]
// (row_offsets: exclusive prefix sum of bin_rows' counts; the importing shader binds it).

fn rank_of_item(q: u32, m: u32) -> u32 {
    var lo = 0u;
    var hi = m;
    while (lo < hi) {   // first rank whose offset exceeds q
        let mid = lo + (hi - lo) / 2u;
        if (row_offsets[mid] <= q) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo - 1u;
}
