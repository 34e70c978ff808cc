//! Triangle meshes (e.g. iso-surfaces of a reconstruction) as binary PLY or OBJ.
//!
//! Vertices are world coordinates (the scene's units); triangles index vertices from 0 and are
//! wound counter-clockwise seen from outside.

use std::path::Path;

use crate::{atomic_write, IoError};

fn check_indices(path: &Path, vertices: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<(), IoError> {
    if let Some((t, tri)) =
        triangles.iter().enumerate().find(|(_, tri)| tri.iter().any(|&i| i as usize >= vertices.len()))
    {
        return Err(IoError::invalid(
            path,
            format!("triangle {t} {tri:?} indexes past the {} vertices", vertices.len()),
        ));
    }
    Ok(())
}

/// Writes a binary little-endian PLY: `vertex` with float `x y z`, `face` with a `uchar`-counted
/// `int` index list.
pub fn write_ply(path: &Path, vertices: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<(), IoError> {
    check_indices(path, vertices, triangles)?;
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by fluidnerf\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        vertices.len(),
        triangles.len()
    );
    atomic_write(path, |w| {
        w.write_all(header.as_bytes())?;
        for v in vertices {
            for c in v {
                w.write_all(&c.to_le_bytes())?;
            }
        }
        for t in triangles {
            w.write_all(&[3u8])?;
            for &i in t {
                w.write_all(&(i as i32).to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// Writes a Wavefront OBJ (`v x y z` lines, then 1-based `f a b c` lines).
pub fn write_obj(path: &Path, vertices: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<(), IoError> {
    check_indices(path, vertices, triangles)?;
    atomic_write(path, |w| {
        writeln!(w, "# written by fluidnerf: {} vertices, {} triangles", vertices.len(), triangles.len())?;
        for v in vertices {
            writeln!(w, "v {} {} {}", v[0], v[1], v[2])?;
        }
        for t in triangles {
            writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const V: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.5]];
    const T: [[u32; 3]; 4] = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];

    #[test]
    fn ply_layout() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("m.ply");
        write_ply(&p, &V, &T).expect("write");
        let bytes = std::fs::read(&p).expect("read");
        let end = bytes.windows(11).position(|w| w == b"end_header\n").expect("header") + 11;
        let header = std::str::from_utf8(&bytes[..end]).expect("utf8");
        assert!(header.contains("element vertex 4") && header.contains("element face 4"));
        assert_eq!(bytes.len() - end, 4 * 12 + 4 * 13);
        let z3 = f32::from_le_bytes(bytes[end + 3 * 12 + 8..end + 3 * 12 + 12].try_into().expect("4 bytes"));
        assert_eq!(z3, 1.5);
        let face0 = end + 48;
        assert_eq!(bytes[face0], 3);
        assert_eq!(i32::from_le_bytes(bytes[face0 + 5..face0 + 9].try_into().expect("4 bytes")), 2);
    }

    #[test]
    fn obj_is_one_based_and_bad_indices_fail() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("m.obj");
        write_obj(&p, &V, &T).expect("write");
        let text = std::fs::read_to_string(&p).expect("read");
        assert!(text.contains("\nf 1 3 2\n") && text.contains("v 0 0 1.5\n"), "{text}");
        let err = write_ply(&p, &V, &[[0, 1, 4]]).expect_err("index 4");
        assert!(err.to_string().contains("triangle 0"), "{err}");
    }
}
