//! The form-factor row cache: rows of patches that have shot, kept for when
//! they shoot again. A row is keyed by its shooter patch, hemisphere centre
//! and resolution tier, so a hit gives exactly the values a fresh drawing
//! would. Whether a row is kept depends only on counts summed over ranks, so
//! every rank keeps or drops a row alike (and every rank hits alike).

use crate::formfactor::Row;
use std::collections::HashMap;

/// Memory the form-factor row cache may use, in bytes per rank (summed over
/// ranks before each decision, so every rank keeps or drops a row alike).
pub const ROW_CACHE_BYTES: u64 = 1 << 30;

/// A cached row's shooter patch, hemisphere centre (f32 bits) and tier.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RowKey {
    /// The shooter patch.
    pub patch: u32,
    /// The hemisphere's centre, as f32 bits (exact equality).
    pub centre: [u32; 3],
    /// The resolution tier (0: fine, 1: coarse).
    pub tier: u8,
}

impl RowKey {
    /// The key of a shot of `patch` at `centre` in tier `tier`.
    pub fn new(patch: u32, centre: glam::Vec3, tier: usize) -> Self {
        Self {
            patch,
            centre: centre.to_array().map(f32::to_bits),
            tier: tier as u8,
        }
    }
}

/// Rows of shooters that have shot, within a byte budget over all ranks.
#[derive(Default)]
pub struct RowCache {
    rows: HashMap<RowKey, Row>,
    /// The last row computed, until it is known whether it fits.
    pending: Option<(RowKey, Row)>,
    /// Bytes the cache holds over all ranks.
    bytes: u64,
    /// Bytes it may hold over all ranks (0: no cache).
    budget: u64,
}

impl RowCache {
    /// A cache of at most `budget` bytes over all ranks (0 keeps nothing).
    pub fn new(budget: u64) -> Self {
        Self {
            budget,
            ..Self::default()
        }
    }

    /// The cache a render's options ask for on `ranks` ranks.
    pub fn for_ranks(enabled: bool, ranks: usize) -> Self {
        Self::new(if enabled {
            ROW_CACHE_BYTES * ranks as u64
        } else {
            0
        })
    }

    /// The row kept for `key`, if any.
    pub fn get(&self, key: &RowKey) -> Option<&Row> {
        self.rows.get(key)
    }

    /// Whether the cache keeps anything at all.
    pub fn enabled(&self) -> bool {
        self.budget > 0
    }

    /// Offers the row just computed; it is kept or dropped at the next
    /// [`RowCache::settle`], once every rank's share of its size is known.
    pub fn offer(&mut self, key: RowKey, row: Row) {
        if self.enabled() {
            self.pending = Some((key, row));
        }
    }

    /// Bytes of the offered row not yet decided on (this rank's share).
    pub fn pending_bytes(&self) -> u64 {
        self.pending.as_ref().map_or(0, |(_, r)| r.bytes() as u64)
    }

    /// Keeps the offered row if the cache has room for `all_ranks_bytes`
    /// (its bytes summed over ranks: the same number on every rank).
    pub fn settle(&mut self, all_ranks_bytes: u64) {
        if let Some((key, row)) = self.pending.take() {
            if self.bytes + all_ranks_bytes <= self.budget {
                self.bytes += all_ranks_bytes;
                self.rows.insert(key, row);
            }
        }
    }

    /// Rows kept.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether no row is kept.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(n: usize) -> Row {
        Row {
            columns: 1,
            ids: (0..n as u32).collect(),
            values: vec![0.5; n],
            ..Row::default()
        }
    }

    fn key(patch: u32) -> RowKey {
        RowKey::new(patch, glam::Vec3::new(1.0, 2.0, 3.0), 0)
    }

    #[test]
    fn a_row_is_kept_only_once_settled_and_within_the_budget() {
        let one = row(10).bytes() as u64;
        let mut c = RowCache::new(2 * one);
        c.offer(key(0), row(10));
        assert!(c.get(&key(0)).is_none(), "not before it is settled");
        assert_eq!(c.pending_bytes(), one);
        c.settle(one);
        assert_eq!(c.get(&key(0)), Some(&row(10)));
        assert_eq!(c.pending_bytes(), 0);
        // Another rank's share makes the next row too big for what is left.
        c.offer(key(1), row(10));
        c.settle(one + 1);
        assert!(c.get(&key(1)).is_none());
        c.offer(key(2), row(10));
        c.settle(one);
        assert!(c.get(&key(2)).is_some());
        assert_eq!(c.len(), 2);
    }

    #[test]
    fn keys_tell_centres_and_tiers_apart() {
        let mut c = RowCache::new(u64::MAX);
        c.offer(key(3), row(2));
        c.settle(1);
        let moved = RowKey::new(3, glam::Vec3::new(1.0, 2.0, 3.0000002), 0);
        let coarse = RowKey::new(3, glam::Vec3::new(1.0, 2.0, 3.0), 1);
        assert!(c.get(&moved).is_none() && c.get(&coarse).is_none());
        assert!(c.get(&key(3)).is_some());
    }

    #[test]
    fn a_disabled_cache_keeps_nothing() {
        let mut c = RowCache::for_ranks(false, 4);
        c.offer(key(0), row(3));
        assert_eq!(c.pending_bytes(), 0);
        c.settle(0);
        assert!(c.is_empty());
        assert_eq!(RowCache::for_ranks(true, 4).budget, 4 * ROW_CACHE_BYTES);
    }
}
