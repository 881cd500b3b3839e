//! The digest of a tri-dexel's crossings, shared by the examples that print it
//! (`dexel_digest`, which records and checks it, and `scene_sweep`).

use twinmill::cutting::stock::TriDexel;

/// FNV-1a 64 over every crossing of the three grids, in the grids' fixed order: each
/// coordinate and normal component bit for bit (little-endian), then the NC line; and the
/// number of crossings.
pub fn digest(stock: &TriDexel) -> (u64, usize) {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    let mut count = 0;
    for g in stock.grids() {
        g.for_each_crossing(|p, c| {
            count += 1;
            for k in 0..3 {
                eat(&p[k].to_bits().to_le_bytes());
                eat(&c.normal[k].to_bits().to_le_bytes());
            }
            eat(&c.line.to_le_bytes());
        });
    }
    (h, count)
}
