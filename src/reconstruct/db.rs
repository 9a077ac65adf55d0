//! Reads the two-view geometries of a COLMAP database (`database.db`, SQLite): how many inlier
//! matches each verified image pair has, and the pixel positions of a pair's inlier matches
//! (its `keypoints` rows and the `data` of its two-view geometry). Read-only; the database is
//! never written.
//!
//! rusqlite (with SQLite built in) rather than the `sqlite3` tool or a hand-written reader: a
//! real SQLite reads COLMAP's file exactly as COLMAP wrote it (journal and all), needs no
//! program on PATH, and the tables are a documented part of COLMAP's database format.

use super::epipolar;
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
    let (conn, err) = open(db)?;
    let names = images(&conn).map_err(err)?;
    let mut out = HashMap::new();
    let rows = id_counts(&conn, "SELECT pair_id, rows FROM two_view_geometries").map_err(err)?;
    for (pair, n) in rows {
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

/// An image pair of the database.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pair {
    /// COLMAP's image ids, the smaller first.
    pub ids: (i64, i64),
    /// Their names.
    pub names: (String, String),
    /// Inlier matches of their two-view geometry.
    pub inliers: usize,
}

/// The image pairs whose two-view geometry is calibrated (COLMAP's configuration 2: an
/// essential matrix, not a homography, explains it) among the images named `among`, most
/// inliers first.
pub fn calibrated_pairs(db: &Path, among: &[String]) -> Result<Vec<Pair>> {
    let (conn, err) = open(db)?;
    let mut names = images(&conn).map_err(err)?;
    names.retain(|_, name| among.contains(name));
    let sql = "SELECT pair_id, rows FROM two_view_geometries WHERE config = 2 ORDER BY rows DESC, pair_id";
    let mut out = Vec::new();
    for (pair, n) in id_counts(&conn, sql).map_err(err)? {
        let (a, b) = pair_ids(pair);
        if let (Some(na), Some(nb)) = (names.get(&a), names.get(&b)) {
            out.push(Pair {
                ids: (a, b),
                names: (na.clone(), nb.clone()),
                inliers: usize::try_from(n).unwrap_or(0),
            });
        }
    }
    Ok(out)
}

/// The inlier matches of image pairs, as pixel positions in the pair's first and second image:
/// per pair of `pairs` (image names), its matches in that order, empty when the pair has no
/// two-view geometry or an image is not in the database.
pub fn inlier_points(
    db: &Path,
    pairs: &[(String, String)],
) -> Result<Vec<Vec<(epipolar::Px, epipolar::Px)>>> {
    let (conn, err) = open(db)?;
    let ids: HashMap<String, i64> = (images(&conn).map_err(err)?.into_iter())
        .map(|(id, name)| (name, id))
        .collect();
    let mut keypoints: HashMap<i64, Vec<epipolar::Px>> = HashMap::new();
    let mut kq = conn
        .prepare("SELECT rows, cols, data FROM keypoints WHERE image_id = ?1")
        .map_err(err)?;
    let mut mq = conn
        .prepare("SELECT rows, cols, data FROM two_view_geometries WHERE pair_id = ?1")
        .map_err(err)?;
    let mut out = Vec::with_capacity(pairs.len());
    for (a, b) in pairs {
        let (Some(&ia), Some(&ib)) = (ids.get(a), ids.get(b)) else {
            out.push(Vec::new());
            continue;
        };
        for id in [ia, ib] {
            if let std::collections::hash_map::Entry::Vacant(slot) = keypoints.entry(id) {
                let row = blob_row(&mut kq, id).map_err(err)?;
                slot.insert(row.map_or_else(Vec::new, |(r, c, d)| points(r, c, d.as_deref())));
            }
        }
        let (lo, hi) = if ia < ib { (ia, ib) } else { (ib, ia) };
        let matches = blob_row(&mut mq, lo * PAIR_BASE + hi)
            .map_err(err)?
            .map_or_else(Vec::new, |(r, c, d)| index_pairs(r, c, d.as_deref()));
        let (ka, kb) = (&keypoints[&ia], &keypoints[&ib]);
        let pts = matches
            .into_iter()
            .map(|(i, j)| if ia < ib { (i, j) } else { (j, i) })
            .filter_map(|(i, j)| Some((*ka.get(i)?, *kb.get(j)?)))
            .collect();
        out.push(pts);
    }
    Ok(out)
}

/// A matrix blob of COLMAP's tables: `rows`, `cols`, `data`.
type Blob = (i64, i64, Option<Vec<u8>>);

/// The blob of the row `key` selects (None: no such row).
fn blob_row(q: &mut rusqlite::Statement<'_>, key: i64) -> rusqlite::Result<Option<Blob>> {
    use rusqlite::OptionalExtension;
    q.query_row([key], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
        .optional()
}

/// Opens the database read-only, with the error constructor that names it.
fn open(
    db: &Path,
) -> Result<(
    rusqlite::Connection,
    impl Fn(rusqlite::Error) -> Error + Copy + '_,
)> {
    let err = move |e: rusqlite::Error| Error::input(db, format!("COLMAP database: {e}"));
    let flags =
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let conn = rusqlite::Connection::open_with_flags(db, flags).map_err(err)?;
    Ok((conn, err))
}

/// Every image's name by its id.
fn images(conn: &rusqlite::Connection) -> rusqlite::Result<HashMap<i64, String>> {
    let mut q = conn.prepare("SELECT image_id, name FROM images")?;
    let rows = q.query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?)))?;
    rows.collect()
}

/// The (id, count) rows `sql` selects.
fn id_counts(conn: &rusqlite::Connection, sql: &str) -> rusqlite::Result<Vec<(i64, i64)>> {
    let mut q = conn.prepare(sql)?;
    let rows = q.query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, i64>(1)?)))?;
    rows.collect()
}

/// The `(x, y)` of each keypoint row (float32, `cols` per row, x and y first).
fn points(rows: i64, cols: i64, data: Option<&[u8]>) -> Vec<epipolar::Px> {
    let (Ok(rows), Ok(cols)) = (usize::try_from(rows), usize::try_from(cols)) else {
        return Vec::new();
    };
    let Some(data) = data.filter(|d| cols >= 2 && d.len() >= rows * cols * 4) else {
        return Vec::new();
    };
    let f = |k: usize| {
        let b = &data[k * 4..k * 4 + 4];
        f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    (0..rows).map(|r| [f(r * cols), f(r * cols + 1)]).collect()
}

/// The feature index pairs of a matches blob (uint32, 2 per row).
fn index_pairs(rows: i64, cols: i64, data: Option<&[u8]>) -> Vec<(usize, usize)> {
    let Ok(rows) = usize::try_from(rows) else {
        return Vec::new();
    };
    let Some(data) = data.filter(|d| cols == 2 && d.len() >= rows * 8) else {
        return Vec::new();
    };
    let u = |k: usize| {
        let b = &data[k * 4..k * 4 + 4];
        u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize
    };
    (0..rows).map(|r| (u(2 * r), u(2 * r + 1))).collect()
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

    #[test]
    fn inlier_points_are_the_matched_keypoints_in_the_pairs_order() {
        let dir = tempfile::tempdir().unwrap();
        let db = dir.path().join("database.db");
        let c = rusqlite::Connection::open(&db).unwrap();
        c.execute_batch(
            "CREATE TABLE images (image_id INTEGER PRIMARY KEY, name TEXT, camera_id INTEGER);
             CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB);
             CREATE TABLE two_view_geometries (pair_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB, config INTEGER);
             INSERT INTO images VALUES (1, 'b.jpg', 1), (2, 'a.jpg', 1), (3, 'c.jpg', 1);",
        )
        .unwrap();
        // Keypoints (x, y and 4 affine values, float32) of images 1 and 2, and the inlier
        // matches of pair (1, 2): feature 0 of image 1 with feature 1 of image 2, 1 with 0.
        let kp = |pts: &[[f32; 2]]| -> Vec<u8> {
            pts.iter()
                .flat_map(|p| [p[0], p[1], 1.0, 0.0, 0.0, 1.0])
                .flat_map(f32::to_le_bytes)
                .collect()
        };
        c.execute(
            "INSERT INTO keypoints VALUES (1, 2, 6, ?1), (2, 2, 6, ?2)",
            rusqlite::params![kp(&[[1.0, 2.0], [3.0, 4.0]]), kp(&[[5.0, 6.0], [7.0, 8.0]])],
        )
        .unwrap();
        let m: Vec<u8> = [0u32, 1, 1, 0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        c.execute(
            "INSERT INTO two_view_geometries VALUES (?2, 2, 2, ?1, 2)",
            rusqlite::params![m, PAIR_BASE + 2],
        )
        .unwrap();
        drop(c);
        let pairs = [
            ("b.jpg".to_string(), "a.jpg".to_string()),
            ("a.jpg".to_string(), "b.jpg".to_string()),
            ("b.jpg".to_string(), "c.jpg".to_string()),
            ("b.jpg".to_string(), "zz.jpg".to_string()),
        ];
        let pts = inlier_points(&db, &pairs).unwrap();
        assert_eq!(
            pts[0],
            vec![([1.0, 2.0], [7.0, 8.0]), ([3.0, 4.0], [5.0, 6.0])]
        );
        assert_eq!(
            pts[1],
            vec![([7.0, 8.0], [1.0, 2.0]), ([5.0, 6.0], [3.0, 4.0])]
        );
        assert!(pts[2].is_empty() && pts[3].is_empty());
    }
}
