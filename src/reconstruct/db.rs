//! Reads the two-view geometries of a COLMAP database (`database.db`, SQLite): how many inlier
//! matches each verified image pair has. Read-only; the database is never written.
//!
//! rusqlite (with SQLite built in) rather than the `sqlite3` tool or a hand-written reader: a
//! real SQLite reads COLMAP's file exactly as COLMAP wrote it (journal and all), needs no
//! program on PATH, and the tables are a documented part of COLMAP's database format.

use crate::error::{Error, Result};
use std::collections::HashMap;
use std::path::Path;

/// COLMAP's pair id: `image_id1 * 2147483647 + image_id2` with `image_id1 < image_id2`.
const PAIR_BASE: i64 = 2_147_483_647;

/// The two image ids of a pair id.
pub fn pair_ids(pair_id: i64) -> (i64, i64) {
    let second = pair_id % PAIR_BASE;
    ((pair_id - second) / PAIR_BASE, second)
}

/// Inlier matches per image pair, keyed by the two image names in name order; a pair that was
/// matched but not verified has 0, a pair never matched is absent.
pub fn inliers(db: &Path) -> Result<HashMap<(String, String), usize>> {
    let err = |e: rusqlite::Error| Error::input(db, format!("COLMAP database: {e}"));
    let conn = rusqlite::Connection::open_with_flags(
        db,
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
    )
    .map_err(err)?;
    let mut names: HashMap<i64, String> = HashMap::new();
    let mut q = conn
        .prepare("SELECT image_id, name FROM images")
        .map_err(err)?;
    let rows = q
        .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?)))
        .map_err(err)?;
    for row in rows {
        let (id, name) = row.map_err(err)?;
        names.insert(id, name);
    }
    let mut out = HashMap::new();
    let mut q = conn
        .prepare("SELECT pair_id, rows FROM two_view_geometries")
        .map_err(err)?;
    let rows = q
        .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, i64>(1)?)))
        .map_err(err)?;
    for row in rows {
        let (pair, n) = row.map_err(err)?;
        let (a, b) = pair_ids(pair);
        if let (Some(a), Some(b)) = (names.get(&a), names.get(&b)) {
            let key = if a <= b {
                (a.clone(), b.clone())
            } else {
                (b.clone(), a.clone())
            };
            out.insert(key, usize::try_from(n).unwrap_or(0));
        }
    }
    Ok(out)
}

/// The inliers of the pair of images `a` and `b` (either order) in a table from [`inliers`].
pub fn of(table: &HashMap<(String, String), usize>, a: &str, b: &str) -> usize {
    let key = if a <= b {
        (a.to_string(), b.to_string())
    } else {
        (b.to_string(), a.to_string())
    };
    table.get(&key).copied().unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_ids_split_as_colmap_packs_them() {
        assert_eq!(pair_ids(3 * PAIR_BASE + 7), (3, 7));
        assert_eq!(pair_ids(PAIR_BASE + 2), (1, 2));
    }

    #[test]
    fn reads_a_database_with_colmaps_tables() {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("database.db");
        let c = rusqlite::Connection::open(&db).unwrap();
        c.execute_batch(
            "CREATE TABLE images (image_id INTEGER PRIMARY KEY, name TEXT, camera_id INTEGER);
             CREATE TABLE two_view_geometries (pair_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB, config INTEGER);
             INSERT INTO images VALUES (1, 'b.jpg', 1), (2, 'a.jpg', 1), (3, 'c.jpg', 1);",
        )
        .unwrap();
        c.execute(
            "INSERT INTO two_view_geometries VALUES (?1, 42, 2, NULL, 2), (?2, 0, 2, NULL, 0)",
            [PAIR_BASE + 2, 2 * PAIR_BASE + 3],
        )
        .unwrap();
        drop(c);
        let t = inliers(&db).unwrap();
        assert_eq!(of(&t, "b.jpg", "a.jpg"), 42);
        assert_eq!(of(&t, "a.jpg", "b.jpg"), 42);
        assert_eq!(of(&t, "a.jpg", "c.jpg"), 0);
        assert_eq!(of(&t, "b.jpg", "c.jpg"), 0);
        assert_eq!(t.len(), 2);
    }
}
