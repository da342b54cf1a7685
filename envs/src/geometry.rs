//! Axis-aligned boxes and segment tests for the gridworld.

/// A closed axis-aligned box `[x0, x1] x [y0, y1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rect {
    pub x0: f64,
    pub x1: f64,
    pub y0: f64,
    pub y1: f64,
}

impl Rect {
    pub(crate) const fn new(x0: f64, x1: f64, y0: f64, y1: f64) -> Self {
        Self { x0, x1, y0, y1 }
    }

    /// Whether the point lies in the box (borders included).
    #[cfg(test)]
    pub(crate) fn contains(&self, p: [f64; 2]) -> bool {
        (self.x0..=self.x1).contains(&p[0]) && (self.y0..=self.y1).contains(&p[1])
    }

    /// Whether any point of the segment `a -> b` lies in the box (Liang-Barsky clipping).
    pub(crate) fn hit_by_segment(&self, a: [f64; 2], b: [f64; 2]) -> bool {
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for (p, d, lo, hi) in [
            (a[0], b[0] - a[0], self.x0, self.x1),
            (a[1], b[1] - a[1], self.y0, self.y1),
        ] {
            if d == 0.0 {
                if p < lo || p > hi {
                    return false;
                }
            } else {
                let (ta, tb) = ((lo - p) / d, (hi - p) / d);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
                if t0 > t1 {
                    return false;
                }
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_segment_crossing_a_thin_box_hits_it_though_both_ends_are_outside() {
        let wall = Rect::new(0.0, 0.5, 0.375, 0.4);
        assert!(wall.hit_by_segment([0.2, 0.36], [0.2, 0.41]));
        assert!(!wall.contains([0.2, 0.36]) && !wall.contains([0.2, 0.41]));
        assert!(!wall.hit_by_segment([0.2, 0.30], [0.2, 0.37]));
        assert!(!wall.hit_by_segment([0.51, 0.30], [0.51, 0.45]));
        // diagonal that clips the corner
        assert!(wall.hit_by_segment([0.49, 0.41], [0.51, 0.39]));
    }
}
