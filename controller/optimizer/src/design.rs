//! Space-filling designs: a digitally shifted (scrambled) Sobol sequence.
//!
//! The Sobol points come from `sobol_burley`'s table (Joe and Kuo's published
//! direction numbers for 256 dimensions, 2^16 points), taken in Gray-code
//! order; a random XOR shift per dimension (from the caller's seed) scrambles
//! them while keeping their stratification. Past the table — dimension 256 and
//! beyond, or point 2^16 and beyond — the sequence continues with Burley's
//! padding: for each block of 256 dimensions and of 2^16 points, an
//! independently Owen-scrambled Sobol sequence from the same crate. Points are
//! computed from their index, so the only state a caller needs is the index
//! and the shift.

use serde::{Deserialize, Serialize};
use sobol_burley::NUM_DIMENSIONS;
use sobol_burley::parts::sobol_rev;

use crate::rng::Rng;

/// Points in the table (`sobol_burley`'s limit).
const POINTS: u64 = 1 << 16;

/// A scrambled Sobol sequence over `(0, 1)^dim`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Sobol {
    shift: Vec<u32>,
}

impl Sobol {
    /// Unscrambled sequence (point 0 is the origin's cell).
    pub fn new(dim: usize) -> Self {
        Self {
            shift: vec![0; dim],
        }
    }

    /// Digitally shifted by random bits from `rng`.
    pub fn scrambled(dim: usize, rng: &mut Rng) -> Self {
        let shift = (0..dim).map(|_| (rng.next_u64() >> 32) as u32).collect();
        Self { shift }
    }

    pub fn dim(&self) -> usize {
        self.shift.len()
    }

    /// The point with the given index.
    pub fn point(&self, index: u64) -> Vec<f64> {
        let gray = index ^ (index >> 1);
        self.shift
            .iter()
            .enumerate()
            .map(|(d, &shift)| match u32::try_from(d) {
                Ok(dim) if index < POINTS && dim < NUM_DIMENSIONS => {
                    let x = sobol_rev((gray as u32).reverse_bits(), dim).reverse_bits() ^ shift;
                    // Centre of the 2^-32 cell so no coordinate is exactly 0.
                    (f64::from(x) + 0.5) / 4_294_967_296.0
                }
                _ => self.padding(index, d),
            })
            .collect()
    }

    /// Coordinate `d` of point `index` outside the table: Owen-scrambled Sobol
    /// with one seed per block of 2^16 points and of 256 dimensions.
    fn padding(&self, index: u64, d: usize) -> f64 {
        let dims = NUM_DIMENSIONS as usize;
        let mut block = Rng::seed_from_u64((index / POINTS) ^ (((d / dims) as u64) << 32));
        let seed = self.shift[d - d % dims] ^ (block.next_u64() >> 32) as u32;
        let v = sobol_burley::sample((index % POINTS) as u32, (d % dims) as u32, seed);
        // Centre of the 2^-23 cell.
        f64::from(v) + 0.5 / f64::from(1u32 << 23)
    }

    /// Points `start..start + n`.
    pub fn points(&self, start: u64, n: usize) -> Vec<Vec<f64>> {
        (0..n as u64).map(|i| self.point(start + i)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_dimension_is_stratified() {
        // The first 2^k points of each 1-D projection hit each dyadic interval once,
        // scrambled or not.
        let mut rng = Rng::seed_from_u64(3);
        let s = Sobol::scrambled(20, &mut rng);
        let pts = s.points(0, 64);
        for d in 0..20 {
            let mut seen = [false; 64];
            for p in &pts {
                let cell = (p[d] * 64.0) as usize;
                assert!(!seen[cell], "dimension {d} cell {cell} hit twice");
                seen[cell] = true;
            }
        }
    }

    #[test]
    fn same_seed_same_points_other_seed_other_points() {
        let a = Sobol::scrambled(5, &mut Rng::seed_from_u64(1)).points(0, 8);
        let b = Sobol::scrambled(5, &mut Rng::seed_from_u64(1)).points(0, 8);
        let c = Sobol::scrambled(5, &mut Rng::seed_from_u64(2)).points(0, 8);
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(a.iter().flatten().all(|&v| v > 0.0 && v < 1.0));
    }

    #[test]
    fn past_the_crates_limits_the_points_stay_stratified() {
        // Dimensions past 256 and indices past 2^16 come from the padding
        // sequences: each 1-D projection of a dyadic block is still stratified.
        let s = Sobol::scrambled(300, &mut Rng::seed_from_u64(9));
        for start in [0, POINTS] {
            let pts = s.points(start, 32);
            for d in [0, 255, 256, 299] {
                let mut seen = [false; 32];
                for p in &pts {
                    let cell = (p[d] * 32.0) as usize;
                    assert!(
                        !seen[cell],
                        "start {start} dimension {d} cell {cell} hit twice"
                    );
                    seen[cell] = true;
                }
            }
            // Dimension 256 is not a copy of dimension 0.
            assert!(pts.iter().any(|p| p[0] != p[256]));
        }
        assert_ne!(s.point(0), s.point(POINTS));
    }

    #[test]
    fn first_points_match_the_reference_sequence() {
        // Unscrambled Sobol, dimensions 1-3 (Joe & Kuo's reference output).
        let want = [
            [0.5, 0.5, 0.5],
            [0.75, 0.25, 0.25],
            [0.25, 0.75, 0.75],
            [0.375, 0.375, 0.625],
            [0.875, 0.875, 0.125],
        ];
        let s = Sobol::new(3);
        for (i, w) in want.iter().enumerate() {
            let p = s.point(i as u64 + 1);
            for (a, b) in p.iter().zip(w) {
                assert!((a - b).abs() < 1e-9, "point {}: {p:?} vs {w:?}", i + 1);
            }
        }
    }

    #[test]
    fn two_dimensional_projections_cover_the_square() {
        // 256 points on an 8x8 grid (4 expected per cell): uniform random points leave
        // an empty cell in ~70 % of pairs; Sobol pairs almost never do (2 of the 45
        // pairs of the first 10 dimensions have a checkerboard at this resolution,
        // a known property of some Sobol projections).
        let s = Sobol::scrambled(10, &mut Rng::seed_from_u64(5));
        let pts = s.points(0, 256);
        let mut with_empty = 0;
        for a in 0..10 {
            for b in 0..a {
                let mut cells = [0u32; 64];
                for p in &pts {
                    cells[(p[a] * 8.0) as usize * 8 + (p[b] * 8.0) as usize] += 1;
                }
                with_empty += usize::from(cells.contains(&0));
            }
        }
        assert!(
            with_empty <= 3,
            "{with_empty} of 45 pairs leave a cell empty"
        );
    }
}
