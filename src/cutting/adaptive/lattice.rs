//! The lattice the adaptive mesh is built on: vertex keys (a crossing's lattice edge, a
//! corner's cell face, a fan centre's leaf) and the inside/outside of lattice points read
//! from the z rays a column word at a time.
//!
//! **Invariant:** a vertex is named by lattice data alone, so every leaf that uses it names
//! it alike; reads the stock only.

use super::*;

// ---------------------------------------------------------------------------------------
// Vertex keys: 2-bit tag, then fields. Crossings: axis and lattice point; corners: face
// axis, slot and the cell face's lower lattice point; fan centres: tree, node, piece.

pub(super) type Key = u128;
const TAG_CORNER: Key = 1 << 126;
const TAG_LOCAL: Key = 2 << 126;

fn point_bits(p: [isize; 3]) -> Key {
    p.iter()
        .fold(0, |acc, &c| acc << 32 | (c + 1) as u32 as Key)
}

pub(super) fn crossing_key(axis: usize, p: [isize; 3]) -> Key {
    (axis as Key) << 96 | point_bits(p)
}

pub(super) fn corner_key(n: usize, slot: usize, p: [isize; 3]) -> Key {
    TAG_CORNER | (n as Key) << 96 | (slot as Key) << 98 | point_bits(p)
}

pub(super) fn local_key(tree: usize, node: usize, piece: usize) -> Key {
    TAG_LOCAL | (tree as Key) << 64 | (node as Key) << 32 | piece as Key
}

#[derive(Clone, Copy, Debug)]
pub(super) struct Vtx {
    pub(super) key: Key,
    pub(super) p: Point3,
    pub(super) n: Vector3,
    pub(super) corner: bool,
}

// ---------------------------------------------------------------------------------------
// The lattice read from the z rays, a column word at a time.

pub(super) struct Lat<'a> {
    pub(super) f: Frame<'a>,
}

/// Bits `lo..=hi` set (hi − lo ≤ 63).
pub(super) fn bit_range(lo: usize, hi: usize) -> u64 {
    let w = hi - lo + 1;
    (if w >= 64 { u64::MAX } else { (1u64 << w) - 1 }) << lo
}

pub(super) fn point(n: usize, c: isize, u: isize, v: isize) -> [isize; 3] {
    let mut p = [0; 3];
    p[n] = c;
    p[(n + 1) % 3] = u;
    p[(n + 2) % 3] = v;
    p
}

impl Lat<'_> {
    pub(super) fn pos(&self, p: [isize; 3]) -> Point3 {
        Point3::new(
            self.f.coord(0, p[0]),
            self.f.coord(1, p[1]),
            self.f.coord(2, p[2]),
        )
    }

    /// The first lattice k whose z is at or above `t`.
    pub(super) fn first_at_or_above(&self, t: Real) -> isize {
        let nz = self.f.n[2] as isize;
        let g = ((t - self.f.o[2]) / self.f.h[2]).ceil();
        let mut k = if g.is_finite() {
            (g.clamp(-2.0, (nz + 2) as Real)) as isize
        } else {
            0
        };
        while self.f.coord(2, k - 1) >= t && k > -2 {
            k -= 1;
        }
        while self.f.coord(2, k) < t && k < nz + 2 {
            k += 1;
        }
        k
    }

    /// Bit `t` (0 ≤ t ≤ s ≤ 63): lattice point (i, j, k0 + t) is inside, read on its z ray
    /// (lo ≤ z < hi; points off the rays or outside 0 ≤ k < nz are outside), as
    /// [`crate::cutting::mesh`] reads it.
    pub(super) fn column(&self, i: isize, j: isize, k0: isize, s: usize) -> u64 {
        let [nx, ny, nz] = self.f.n;
        if i < 0 || j < 0 || i >= nx as isize || j >= ny as isize {
            return 0;
        }
        let klo = k0.max(0);
        let khi = (k0 + s as isize).min(nz as isize - 1);
        if klo > khi {
            return 0;
        }
        let mut m = 0;
        for seg in self.f.stock.grids()[2].ray(i as usize, j as usize) {
            let a = self.first_at_or_above(seg.lo.t).max(klo);
            let b = (self.first_at_or_above(seg.hi.t) - 1).min(khi);
            if a <= b {
                m |= bit_range((a - k0) as usize, (b - k0) as usize);
            }
        }
        m
    }

    pub(super) fn crossing(&self, axis: usize, p: [isize; 3], inside_low: bool) -> (Vtx, bool) {
        let (q, n, found) = self.f.crossing(axis, p, inside_low);
        (
            Vtx {
                key: crossing_key(axis, p),
                p: q,
                n,
                corner: false,
            },
            found,
        )
    }
}
