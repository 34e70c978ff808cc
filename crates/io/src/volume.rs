//! Volumes on disk: `.npy`, `.vti` (VTK XML ImageData), raw f32 with a JSON sidecar, and TIFF
//! stacks.
//!
//! [`Volume`] is cell-centred, x fastest (`data[(k * ny + j) * nx + i]`), filling its
//! [`Aabb`]. On disk:
//! - `.npy`: shape `(nz, ny, nx)`, C order, little-endian f32 (`<f4`). The file holds no box,
//!   so [`read_npy`] takes it. Reading also accepts f64, u8 and u16 (converted to f32).
//! - `.vti`: VTK XML ImageData, one Float32 point-data array `value`, appended raw binary
//!   (UInt64 headers, little-endian), which ParaView and the Python `vtk` package read.
//!   `Origin = aabb.min + spacing / 2` because VTK puts point data at grid points, and our
//!   values live at voxel centres; `Spacing` is the voxel size; `WholeExtent = 0 nx−1 0 ny−1
//!   0 nz−1`. ParaView therefore shows every value at its voxel centre, in world units. A volume
//!   of a time-resolved field records its instant as the field data `TimeValue`
//!   ([`write_vti_at`]), ParaView's time of the file.
//!   [`read_vti`] reads every mode VTK's writer has (ASCII, inline base64, appended base64 or
//!   raw; uncompressed or zlib), point or cell data.
//! - raw: little-endian f32 in the same order, plus a sidecar `<file>.json` holding `dims`
//!   `[nx, ny, nz]`, `aabb`, `spacing`, `dtype` (`"<f4"`) and `order` (`"x fastest"`), and
//!   for a volume of a time-resolved field its instant `time`.
//! - `.tif`: a TIFF stack, page `k` the z-slice `k` (row `j`, column `i`), 32-bit float,
//!   calibrated for ImageJ and Fiji: the resolution tags give the voxel's width and height in
//!   the description's `unit`, `spacing` its depth, and `xorigin`/`yorigin`/`zorigin` (in
//!   voxels, ImageJ's convention) place the box. NumPy's `tifffile` reads it as `(nz, ny, nx)`.

use std::io::Write;
use std::path::{Path, PathBuf};

use fluidnerf_core::glam::DVec3;
use fluidnerf_core::{Aabb, Volume};
use npyz::WriterBuilder;
use serde::{Deserialize, Serialize};

use crate::{atomic_write, IoError};

mod stack;
pub use stack::{is_length_unit, read_tiff_stack, tiff_stack_unit, write_tiff_stack};

/// Reads a `.npy` of shape `(nz, ny, nx)` as a volume filling `aabb`. Fortran-order files
/// (NumPy writes them for transposed arrays, `fortran_order: True`) are reordered on read, so
/// the element at index `[k, j, i]` is voxel `(i, j, k)` either way.
pub fn read_npy(path: &Path, aabb: Aabb) -> Result<Volume, IoError> {
    let bytes = crate::read_input(path, "volume file")?;
    let npy = npyz::NpyFile::new(&bytes[..]).map_err(|e| IoError::invalid(path, format!("not a .npy file: {e}")))?;
    let fortran = npy.order() == npyz::Order::Fortran;
    let shape = npy.shape().to_vec();
    if shape.len() != 3 || shape.contains(&0) {
        return Err(IoError::invalid(path, format!("expected a 3-D array of shape (nz, ny, nx), got shape {shape:?}")));
    }
    let dims = [shape[2] as usize, shape[1] as usize, shape[0] as usize];
    let dtype = npy.dtype();
    // A corrupt header can claim any shape: refuse one the file cannot hold before allocating.
    let item = match &dtype {
        npyz::DType::Plain(ts) => ts.size_field().max(1),
        _ => 1,
    };
    let claimed = shape.iter().try_fold(item, |acc, &d| acc.checked_mul(d));
    // Against the data after the header: a file cut short by less than its header's length
    // failed half way through reading, as "failed to fill whole buffer".
    let data_bytes = bytes.len().saturating_sub(npy_data_offset(&bytes)) as u64;
    match claimed {
        None => {
            return Err(IoError::invalid(path, format!("shape {shape:?} needs more data than any file holds")));
        }
        Some(b) if b > data_bytes => {
            return Err(IoError::invalid(
                path,
                format!(
                    "shape {shape:?} of {} needs {b} bytes of data, but {data_bytes} follow the header (a truncated \
                     file?)",
                    dtype.descr()
                ),
            ));
        }
        Some(_) => {}
    }
    let bad = |e: std::io::Error| IoError::invalid(path, format!("cannot read the array data: {e}"));
    let data: Vec<f32> = match &dtype {
        npyz::DType::Plain(ts) => match (ts.type_char(), ts.size_field()) {
            (npyz::TypeChar::Float, 4) => npy.into_vec::<f32>().map_err(bad)?,
            (npyz::TypeChar::Float, 8) => npy.into_vec::<f64>().map_err(bad)?.into_iter().map(|v| v as f32).collect(),
            (npyz::TypeChar::Uint, 1) => npy.into_vec::<u8>().map_err(bad)?.into_iter().map(f32::from).collect(),
            (npyz::TypeChar::Uint, 2) => npy.into_vec::<u16>().map_err(bad)?.into_iter().map(f32::from).collect(),
            _ => {
                return Err(IoError::invalid(
                    path,
                    format!("unsupported dtype {} (use f4, f8, u1 or u2)", dtype.descr()),
                ))
            }
        },
        _ => return Err(IoError::invalid(path, format!("unsupported dtype {} (use f4, f8, u1 or u2)", dtype.descr()))),
    };
    let n = dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
    if n != Some(data.len()) {
        return Err(IoError::invalid(path, format!("shape {shape:?} but {} values", data.len())));
    }
    let data = if fortran { fortran_to_x_fastest(dims, &data) } else { data };
    if let Some(why) = uneven_cells(dims, &aabb) {
        log::warn!("{}: {why}", path.display());
    }
    Ok(Volume::from_vec(dims, aabb, data))
}

/// Where the data of the `.npy` file `bytes` begin: after the magic string and version (8
/// bytes), the header's length (2 bytes in version 1, 4 from version 2 on, little-endian) and
/// the header. Past the end for a file too short to say.
fn npy_data_offset(bytes: &[u8]) -> usize {
    let field = |range: std::ops::Range<usize>| {
        bytes.get(range).map(|b| b.iter().rev().fold(0usize, |n, &x| n << 8 | x as usize))
    };
    match bytes.get(6) {
        Some(1) => field(8..10).map_or(usize::MAX, |n| 10 + n),
        _ => field(8..12).map_or(usize::MAX, |n| 12usize.saturating_add(n)),
    }
}

/// Why `dims` voxels look wrong for `aabb`: a `.npy` holds no box, so it is stretched over the
/// one given, and cells far from cubic usually mean an array of another box or a cropped one.
/// Grids made for a box ([`Volume::dims_for`]) stay within 1.34 between axes of two or more
/// cells.
fn uneven_cells(dims: [usize; 3], aabb: &Aabb) -> Option<String> {
    let size = aabb.size();
    let cells: Vec<f64> = (0..3).filter(|&a| dims[a] >= 2).map(|a| size[a] / dims[a] as f64).collect();
    let (lo, hi) = cells.iter().fold((f64::INFINITY, 0f64), |(lo, hi), &c| (lo.min(c), hi.max(c)));
    (cells.len() >= 2 && hi > 1.5 * lo).then(|| {
        format!(
            "{}×{}×{} voxels stretched over the box of {}×{}×{} make cells of {:.4}×{:.4}×{:.4}, far from cubic; \
             is the array from this box?",
            dims[0],
            dims[1],
            dims[2],
            size.x,
            size.y,
            size.z,
            size.x / dims[0] as f64,
            size.y / dims[1] as f64,
            size.z / dims[2] as f64
        )
    })
}

/// Values of an array of shape `(nz, ny, nx)` stored in Fortran order (first index fastest:
/// element `(k, j, i)` at `k + nz (j + ny i)`), reordered x fastest (`(k ny + j) nx + i`), the
/// order of a C-order `(nz, ny, nx)` array.
fn fortran_to_x_fastest(dims: [usize; 3], data: &[f32]) -> Vec<f32> {
    let [nx, ny, nz] = dims;
    let mut out = Vec::with_capacity(data.len());
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                out.push(data[k + nz * (j + ny * i)]);
            }
        }
    }
    out
}

/// Writes a volume as a little-endian f32 `.npy` of shape `(nz, ny, nx)`, C order.
pub fn write_npy(path: &Path, volume: &Volume) -> Result<(), IoError> {
    let [nx, ny, nz] = volume.dims;
    atomic_write(path, |w| {
        // npyz writes the header; the data go out in bulk (element-wise pushes are 3x slower).
        let w = npyz::WriteOptions::<f32>::new()
            .default_dtype()
            .shape(&[nz as u64, ny as u64, nx as u64])
            .writer(w)
            .write_header_only()?;
        write_f32_le(w, &volume.data)
    })
}

/// Writes a volume as VTK XML ImageData (`.vti`, appended raw binary; see the module docs).
pub fn write_vti(path: &Path, volume: &Volume) -> Result<(), IoError> {
    write_vti_at(path, volume, None)
}

/// [`write_vti`], recording the instant `time` a volume of a time-resolved field holds as the
/// dataset's `TimeValue` field data, which ParaView reads as the time of the file (and
/// [`vti_time`] reads back).
pub fn write_vti_at(path: &Path, volume: &Volume, time: Option<f64>) -> Result<(), IoError> {
    let [nx, ny, nz] = volume.dims;
    let sp = volume.spacing();
    let origin = volume.aabb.min + 0.5 * sp;
    let extent = format!("0 {} 0 {} 0 {}", nx - 1, ny - 1, nz - 1);
    // `{:?}` writes an f64 that reads back to the same value.
    let field_data = time.map_or(String::new(), |t| {
        format!(
            "    <FieldData>\n      <DataArray type=\"Float64\" Name=\"{TIME_ARRAY}\" NumberOfTuples=\"1\" \
             format=\"ascii\">{t:?}</DataArray>\n    </FieldData>\n"
        )
    });
    let header = format!(
        "<?xml version=\"1.0\"?>\n\
         <VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n\
         \x20 <ImageData WholeExtent=\"{extent}\" Origin=\"{} {} {}\" Spacing=\"{} {} {}\">\n{field_data}\
         \x20   <Piece Extent=\"{extent}\">\n\
         \x20     <PointData Scalars=\"value\">\n\
         \x20       <DataArray type=\"Float32\" Name=\"value\" NumberOfComponents=\"1\" format=\"appended\" offset=\"0\"/>\n\
         \x20     </PointData>\n\
         \x20     <CellData/>\n\
         \x20   </Piece>\n\
         \x20 </ImageData>\n\
         \x20 <AppendedData encoding=\"raw\">\n_",
        origin.x, origin.y, origin.z, sp.x, sp.y, sp.z
    );
    atomic_write(path, |w| {
        w.write_all(header.as_bytes())?;
        w.write_all(&((volume.data.len() * 4) as u64).to_le_bytes())?;
        write_f32_le(w, &volume.data)?;
        w.write_all(b"\n  </AppendedData>\n</VTKFile>\n")
    })
}

fn write_f32_le(w: &mut dyn Write, data: &[f32]) -> std::io::Result<()> {
    let mut buf = Vec::with_capacity(4 * 4096);
    for chunk in data.chunks(4096) {
        buf.clear();
        buf.extend(chunk.iter().flat_map(|v| v.to_le_bytes()));
        w.write_all(&buf)?;
    }
    Ok(())
}

/// The value of `name="..."` in an XML start tag.
fn attribute<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let start = tag.find(&key)? + key.len();
    let len = tag[start..].find('"')?;
    Some(&tag[start..start + len])
}

/// The start tag `<name ...>` (or `<name .../>`) in `text`.
fn start_tag<'a>(text: &'a str, name: &str) -> Option<&'a str> {
    let open = format!("<{name} ");
    let start = text.find(&open)?;
    let len = text[start..].find('>')?;
    Some(&text[start..=start + len])
}

/// Every start tag `<name ...>` (or `<name .../>`) in `text`, in order.
fn start_tags<'a>(text: &'a str, name: &str) -> Vec<&'a str> {
    let open = format!("<{name} ");
    text.match_indices(&open)
        .filter_map(|(start, _)| {
            let len = text[start..].find('>')?;
            Some(&text[start..=start + len])
        })
        .collect()
}

fn numbers<T: std::str::FromStr>(s: &str) -> Option<Vec<T>> {
    s.split_whitespace().map(|t| t.parse().ok()).collect()
}

/// Reads a `.vti` with one scalar point-data array (Float32 or Float64; appended raw binary as
/// [`write_vti`] writes it, appended base64, inline base64 `binary` or ASCII, each binary one
/// uncompressed or zlib-compressed, as VTK's writer stores them), little-endian, axis-aligned (identity
/// `Direction`). Of several arrays, the one `<PointData Scalars="NAME">` (else `<CellData
/// Scalars="NAME">`) names is read; without that attribute, several arrays are refused. Point
/// data is a voxel per point: the box is recovered as `Origin + (i₀ − ½) · Spacing` to
/// `Origin + (i₁ + ½) · Spacing` for the extent `i₀..i₁`. Cell data is a voxel per cell: the box
/// is the extent's, `Origin + i₀ · Spacing` to `Origin + i₁ · Spacing`.
pub fn read_vti(path: &Path) -> Result<Volume, IoError> {
    let bytes = crate::read_input(path, "volume file")?;
    let bad = |what: &str| IoError::invalid(path, format!("not a VTK ImageData file we can read: {what}"));
    // The appended section is binary; only the XML before it is text.
    let xml_end = find(&bytes, b"<AppendedData").unwrap_or(bytes.len());
    let xml = std::str::from_utf8(&bytes[..xml_end]).map_err(|_| bad("header is not UTF-8"))?;
    let file_tag = start_tag(xml, "VTKFile").ok_or_else(|| bad("no <VTKFile> element"))?;
    if attribute(file_tag, "type") != Some("ImageData") {
        return Err(bad("type is not ImageData"));
    }
    if attribute(file_tag, "byte_order").is_some_and(|b| b != "LittleEndian") {
        return Err(bad("only LittleEndian is supported"));
    }
    // ASCII arrays are never compressed, whatever the file says (VTK names its compressor on
    // every file it writes): only binary arrays read it.
    let zlib = match attribute(file_tag, "compressor") {
        None => false,
        Some("vtkZLibDataCompressor") => true,
        Some(other) => {
            return Err(bad(&format!(
                "compressor {other}: only zlib (vtkZLibDataCompressor) or none is read; save the file with zlib or \
                 without compression"
            )))
        }
    };
    let header_u64 = match attribute(file_tag, "header_type") {
        None | Some("UInt32") => false,
        Some("UInt64") => true,
        Some(other) => return Err(bad(&format!("header_type {other}"))),
    };
    let image_tag = start_tag(xml, "ImageData").ok_or_else(|| bad("no <ImageData> element"))?;
    // An attribute of `count` numbers of the kind `what`, or why it is not.
    fn attribute_numbers<T: std::str::FromStr>(
        tag: &str,
        name: &str,
        count: usize,
        what: &str,
    ) -> Result<Vec<T>, String> {
        match attribute(tag, name) {
            None => Err(format!("<ImageData> has no {name}")),
            Some(text) => numbers(text)
                .filter(|e: &Vec<T>| e.len() == count)
                .ok_or_else(|| format!("{name} must be {count} {what}, got {text:?}")),
        }
    }
    let extent: Vec<i64> = attribute_numbers(image_tag, "WholeExtent", 6, "whole numbers").map_err(|e| bad(&e))?;
    let origin: Vec<f64> = attribute_numbers(image_tag, "Origin", 3, "numbers").map_err(|e| bad(&e))?;
    let spacing: Vec<f64> = attribute_numbers(image_tag, "Spacing", 3, "numbers").map_err(|e| bad(&e))?;
    // A Direction that is not nine numbers says nothing readable of the axes: taken as the
    // identity, a rotated grid would be read unrotated.
    if attribute(image_tag, "Direction").is_some() {
        let dir: Vec<f64> = attribute_numbers(image_tag, "Direction", 9, "numbers").map_err(|e| bad(&e))?;
        if dir != [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] {
            return Err(bad("only the identity Direction is supported"));
        }
    }
    // A corrupt extent can claim any size: its count must fit before anything is allocated.
    let side = |a: usize| extent[2 * a + 1].checked_sub(extent[2 * a]).and_then(|d| d.checked_add(1));
    let dims = [side(0), side(1), side(2)];
    let n = dims.iter().try_fold(1i64, |acc, d| d.and_then(|d| acc.checked_mul(d.max(0))));
    let (Some(n), [Some(nx), Some(ny), Some(nz)]) = (n, dims) else {
        return Err(bad("WholeExtent: more voxels than a volume can hold"));
    };
    if n == 0 {
        return Err(bad("empty extent"));
    }
    if n > u32::MAX as i64 {
        return Err(bad(&format!("WholeExtent: {n} voxels, more than a volume can hold (2^32)")));
    }
    let (mut dims, mut n) = ([nx as usize, ny as usize, nz as usize], n as usize);
    // The array to read: the only one, or the one `<PointData Scalars="...">` (else
    // `<CellData Scalars="...">`) names; taking the first of several would read whichever the
    // writer put first (a mask, say) as the field.
    // Arrays of the dataset's field data (a time, say) are not voxels.
    let arrays: Vec<&str> = start_tags(xml, "DataArray")
        .into_iter()
        .filter(|tag| !inside_field_data(xml, tag.as_ptr() as usize - xml.as_ptr() as usize))
        .collect();
    let scalars = start_tag(xml, "PointData")
        .and_then(|t| attribute(t, "Scalars"))
        .or_else(|| start_tag(xml, "CellData").and_then(|t| attribute(t, "Scalars")));
    let array_tag = match (arrays.as_slice(), scalars) {
        ([], _) => return Err(bad("no <DataArray> element")),
        ([one], _) => *one,
        (several, Some(name)) => *several
            .iter()
            .find(|t| attribute(t, "Name") == Some(name))
            .ok_or_else(|| bad(&format!("<PointData Scalars=\"{name}\"> names no <DataArray> of the file")))?,
        (several, None) => {
            let names: Vec<&str> = several.iter().map(|t| attribute(t, "Name").unwrap_or("(unnamed)")).collect();
            return Err(bad(&format!(
                "{} data arrays ({}) and no <PointData Scalars=\"NAME\"> saying which is the field; keep one \
                 array, or name it there",
                several.len(),
                names.join(", ")
            )));
        }
    };
    // Cell data (finite-volume solvers write it) holds a value per cell, between the points:
    // one fewer along each axis.
    let cell_data = {
        let before = &xml[..array_tag.as_ptr() as usize - xml.as_ptr() as usize];
        // Inside a `<CellData>` that is open (not `<CellData/>`, and not closed since).
        before.rfind("<CellData").is_some_and(|at| {
            let tag = &before[at..at + before[at..].find('>').unwrap_or(before.len() - at)];
            !tag.ends_with('/') && !before[at..].contains("</CellData>")
        })
    };
    if cell_data {
        if dims.iter().any(|&d| d < 2) {
            return Err(bad("cell data on a WholeExtent one point thin along an axis, which holds no cells"));
        }
        dims = dims.map(|d| d - 1);
        n = dims.iter().product();
    }
    if attribute(array_tag, "NumberOfComponents").is_some_and(|c| c != "1") {
        return Err(bad("only single-component arrays are supported"));
    }
    let width = match attribute(array_tag, "type") {
        Some("Float32") => 4,
        Some("Float64") => 8,
        other => return Err(bad(&format!("DataArray type {other:?} (Float32 or Float64 expected)"))),
    };
    let data: Vec<f32> = match attribute(array_tag, "format") {
        Some("appended") => {
            let offset: usize =
                attribute(array_tag, "offset").and_then(|o| o.parse().ok()).ok_or_else(|| bad("offset"))?;
            if xml_end == bytes.len() {
                return Err(bad("no <AppendedData> section"));
            }
            let tail = &bytes[xml_end..];
            let tag_end = find(tail, b">").ok_or_else(|| bad("<AppendedData>"))?;
            let tag = std::str::from_utf8(&tail[..=tag_end]).map_err(|_| bad("<AppendedData>"))?;
            let encoding = attribute(tag, "encoding");
            if !matches!(encoding, Some("raw" | "base64")) {
                return Err(bad(&format!("appended data encoding {encoding:?} (raw or base64 expected)")));
            }
            let underscore = find(&tail[tag_end..], b"_").ok_or_else(|| bad("appended data marker '_'"))?;
            // The blocks lie between the marker and the section's closing tag (the last in the
            // file: raw data may hold any bytes), or the file's end when that is cut off.
            let data_start = xml_end + tag_end + underscore + 1;
            let data_end = rfind(&bytes[data_start..], b"</AppendedData>").map_or(bytes.len(), |e| data_start + e);
            let section = data_end - data_start;
            let name = attribute(array_tag, "Name").unwrap_or("(unnamed)");
            if encoding == Some("base64") || zlib {
                // Offsets count bytes of the section as stored: encoded characters for base64.
                let block = bytes.get(data_start + offset..data_end).ok_or_else(|| {
                    bad(&format!(
                        "array \"{name}\": its appended block at offset {offset} lies past the end of the appended \
                         data ({section} bytes)"
                    ))
                })?;
                let payload = if encoding == Some("base64") { Payload::Base64(block) } else { Payload::Raw(block) };
                let raw = decode_array(payload, header_u64, zlib, n * width)
                    .map_err(|e| bad(&format!("array \"{name}\": {e}")))?;
                return placed(path, floats_le(&raw, width), dims, cell_data, &extent, &origin, &spacing);
            }
            let bad_block = |what: String| bad(&format!("array \"{name}\": {what}"));
            let hlen = if header_u64 { 8 } else { 4 };
            if offset.checked_add(hlen).is_none_or(|e| e > section) {
                return Err(bad_block(format!(
                    "its appended block at offset {offset} lies past the end of the appended data ({section} bytes)"
                )));
            }
            let start = data_start + offset;
            let head = &bytes[start..start + hlen];
            let nbytes = if header_u64 {
                u64::from_le_bytes(head.try_into().map_err(|_| bad("header"))?)
            } else {
                u32::from_le_bytes(head.try_into().map_err(|_| bad("header"))?) as u64
            };
            if nbytes != (n * width) as u64 {
                return Err(bad_block(format!("its block holds {nbytes} bytes, the extent needs {}", n * width)));
            }
            let nbytes = n * width;
            let end = offset + hlen + nbytes;
            if end > section {
                return Err(bad_block(format!(
                    "its appended block at offset {offset} ({hlen}-byte header and {nbytes} bytes) runs past the \
                     end of the appended data ({section} bytes): the file is cut short or its header is wrong"
                )));
            }
            // Another array's block starting inside this one's: one of the two is wrong, and
            // this one would be read with the other's header and values.
            let next = arrays
                .iter()
                .filter(|t| attribute(t, "format") == Some("appended"))
                .filter_map(|t| {
                    Some((attribute(t, "Name").unwrap_or("(unnamed)"), attribute(t, "offset")?.parse().ok()?))
                })
                .filter(|&(_, o): &(&str, usize)| o > offset && o < end)
                .min_by_key(|&(_, o)| o);
            if let Some((other, at)) = next {
                return Err(bad_block(format!(
                    "its appended block at offset {offset} ({hlen}-byte header and {nbytes} bytes) runs into the \
                     block of array \"{other}\" at offset {at}"
                )));
            }
            floats_le(&bytes[start + hlen..start + hlen + nbytes], width)
        }
        Some("binary") => {
            let name = attribute(array_tag, "Name").unwrap_or("(unnamed)");
            let start = xml.find(array_tag).ok_or_else(|| bad("DataArray"))? + array_tag.len();
            let len = xml[start..].find("</DataArray>").ok_or_else(|| bad("unterminated DataArray"))?;
            let raw = decode_array(Payload::Base64(&xml.as_bytes()[start..start + len]), header_u64, zlib, n * width)
                .map_err(|e| bad(&format!("array \"{name}\": {e}")))?;
            return placed(path, floats_le(&raw, width), dims, cell_data, &extent, &origin, &spacing);
        }
        Some("ascii") => {
            let start = xml.find(array_tag).ok_or_else(|| bad("DataArray"))? + array_tag.len();
            let len = xml[start..].find("</DataArray>").ok_or_else(|| bad("unterminated DataArray"))?;
            let v: Vec<f32> = numbers(&xml[start..start + len]).ok_or_else(|| bad("non-numeric ASCII data"))?;
            if v.len() != n {
                return Err(bad(&format!("{} ASCII values, the extent needs {n}", v.len())));
            }
            v
        }
        other => return Err(bad(&format!("DataArray format {other:?} (appended, binary or ascii expected)"))),
    };
    placed(path, data, dims, cell_data, &extent, &origin, &spacing)
}

/// The volume of `data` (x fastest, `dims`) where a `.vti`'s extent, origin and spacing put it.
fn placed(
    path: &Path,
    data: Vec<f32>,
    dims: [usize; 3],
    cell_data: bool,
    extent: &[i64],
    origin: &[f64],
    spacing: &[f64],
) -> Result<Volume, IoError> {
    let spacing = DVec3::new(spacing[0], spacing[1], spacing[2]);
    let origin = DVec3::new(origin[0], origin[1], origin[2]);
    // Point `i` of the extent lies at `Origin + i · Spacing`; a voxel is the box around a point,
    // or a cell between points.
    let first = DVec3::new(extent[0] as f64, extent[2] as f64, extent[4] as f64);
    let min = origin + (first - if cell_data { 0.0 } else { 0.5 }) * spacing;
    let max = min + spacing * DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let aabb = Aabb { min, max };
    aabb.validate().map_err(|e| IoError::invalid(path, format!("Origin/Spacing give an invalid box: {e}")))?;
    Ok(Volume::from_vec(dims, aabb, data))
}

/// Little-endian floats `width` bytes wide (4 or 8) as f32.
fn floats_le(raw: &[u8], width: usize) -> Vec<f32> {
    if width == 4 {
        raw.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
    } else {
        raw.chunks_exact(8)
            .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]) as f32)
            .collect()
    }
}

/// A binary `.vti` array as stored: its bytes (appended raw), or their base64 text (inline
/// `binary`, appended `base64`; whitespace is skipped).
enum Payload<'a> {
    Raw(&'a [u8]),
    Base64(&'a [u8]),
}

/// The `want` bytes of a binary `.vti` array (VTK's layout): a block count header of 32 or 64
/// bits (`header_u64`) before the data, or with zlib `[blocks, block size, last block's size,
/// compressed size of each block]` before the compressed blocks. In base64, VTK encodes an
/// uncompressed array's header and data as one text, and a compressed array's header apart from
/// its blocks.
fn decode_array(payload: Payload, header_u64: bool, zlib: bool, want: usize) -> Result<Vec<u8>, String> {
    use base64::Engine;
    use std::io::Read;
    let hlen = if header_u64 { 8 } else { 4 };
    let word = |b: &[u8], k: usize| -> Result<usize, String> {
        let b = b.get(k * hlen..(k + 1) * hlen).ok_or("its header is cut short")?;
        let v = if header_u64 {
            u64::from_le_bytes(b.try_into().map_err(|_| "header")?)
        } else {
            u32::from_le_bytes(b.try_into().map_err(|_| "header")?) as u64
        };
        usize::try_from(v).map_err(|_| format!("a header value of {v}"))
    };
    let b64 = |text: &[u8]| -> Result<Vec<u8>, String> {
        let text: Vec<u8> = text.iter().copied().filter(|c| !c.is_ascii_whitespace()).collect();
        base64::engine::general_purpose::STANDARD
            .decode(&text)
            .map_err(|e| format!("its base64 text does not decode: {e}"))
    };
    // The characters of base64 text (whitespace skipped) that encode its first `bytes` bytes, in
    // whole groups of four.
    let chars_for = |bytes: usize| bytes.div_ceil(3) * 4;
    let (header, blocks): (Vec<u8>, Vec<u8>) = match (&payload, zlib) {
        (Payload::Raw(b), false) => (b.to_vec(), Vec::new()),
        (Payload::Base64(t), false) => (b64(t)?, Vec::new()),
        (Payload::Raw(b), true) => {
            let count = word(b, 0)?;
            let size = hlen.checked_mul(count.checked_add(3).ok_or("too many blocks")?).ok_or("too many blocks")?;
            if size > b.len() {
                return Err(format!("its header names {count} compressed blocks, more than the file holds"));
            }
            (b[..size].to_vec(), b[size..].to_vec())
        }
        (Payload::Base64(t), true) => {
            let text: Vec<u8> = t.iter().copied().filter(|c| !c.is_ascii_whitespace()).collect();
            let first = b64(text.get(..chars_for(hlen)).ok_or("its header is cut short")?)?;
            let count = word(&first, 0)?;
            let size = hlen.checked_mul(count.checked_add(3).ok_or("too many blocks")?).ok_or("too many blocks")?;
            let split = chars_for(size);
            if split > text.len() {
                return Err(format!("its header names {count} compressed blocks, more than the file holds"));
            }
            (b64(&text[..split])?, b64(&text[split..])?)
        }
    };
    if !zlib {
        let nbytes = word(&header, 0)?;
        if nbytes != want {
            return Err(format!("its block holds {nbytes} bytes, the extent needs {want}"));
        }
        return header.get(hlen..hlen + nbytes).map(<[u8]>::to_vec).ok_or_else(|| {
            format!("its block of {nbytes} bytes is cut short ({} bytes)", header.len().saturating_sub(hlen))
        });
    }
    let (count, block, last) = (word(&header, 0)?, word(&header, 1)?, word(&header, 2)?);
    let last = if last == 0 { block } else { last };
    let total = if count == 0 { 0 } else { block * (count - 1) + last };
    if total != want {
        return Err(format!("its {count} compressed blocks hold {total} bytes, the extent needs {want}"));
    }
    let mut out = Vec::with_capacity(want);
    let mut at = 0usize;
    for k in 0..count {
        let csize = word(&header, 3 + k)?;
        let compressed = blocks.get(at..at + csize).ok_or_else(|| format!("compressed block {k} is cut short"))?;
        at += csize;
        let expected = if k + 1 == count { last } else { block };
        let before = out.len();
        flate2::read::ZlibDecoder::new(compressed)
            .take(expected as u64 + 1)
            .read_to_end(&mut out)
            .map_err(|e| format!("compressed block {k} does not inflate: {e}"))?;
        if out.len() - before != expected {
            return Err(format!("compressed block {k} inflates to {} bytes, not {expected}", out.len() - before));
        }
    }
    Ok(out)
}

/// The name of the `.vti` field-data array holding the instant of a time-resolved field's
/// volume, ParaView's.
const TIME_ARRAY: &str = "TimeValue";

/// Whether the byte offset `at` of `xml` lies inside a `<FieldData>` element.
fn inside_field_data(xml: &str, at: usize) -> bool {
    let before = &xml[..at];
    before.rfind("<FieldData").is_some_and(|open| !before[open..].contains("</FieldData>"))
}

/// The instant a `.vti` records as its `TimeValue` field data (as [`write_vti_at`] writes it,
/// in ASCII, and as VTK's and ParaView's writers do: inline binary or appended, raw or base64,
/// zlib-compressed or not; Float32, Float64 or a whole number); None when it records none, or
/// in a form not read here. Reads only the file's XML head and the value's block.
pub fn vti_time(path: &Path) -> Option<f64> {
    use std::io::{Read, Seek, SeekFrom};
    let mut file = std::fs::File::open(path).ok()?;
    let mut head = Vec::new();
    (&mut file).take(1 << 16).read_to_end(&mut head).ok()?;
    let xml_end = find(&head, b"<AppendedData");
    let xml = String::from_utf8_lossy(&head[..xml_end.unwrap_or(head.len())]).into_owned();
    let file_tag = start_tag(&xml, "VTKFile")?;
    let zlib = attribute(file_tag, "compressor") == Some("vtkZLibDataCompressor");
    let header_u64 = attribute(file_tag, "header_type") == Some("UInt64");
    let section = &xml[xml.find("<FieldData")?..];
    let section = &section[..section.find("</FieldData>")?];
    let tag = start_tags(section, "DataArray").into_iter().find(|t| attribute(t, "Name") == Some(TIME_ARRAY))?;
    let (kind, width) = match attribute(tag, "type")? {
        "Float64" => ('f', 8),
        "Float32" => ('f', 4),
        "Int64" => ('i', 8),
        "Int32" => ('i', 4),
        "UInt64" => ('u', 8),
        "UInt32" => ('u', 4),
        _ => return None,
    };
    let text_after = || {
        let at = tag.as_ptr() as usize - section.as_ptr() as usize + tag.len();
        let rest = &section[at..];
        rest.find('<').map(|end| rest[..end].to_string())
    };
    let bytes: Vec<u8> = match attribute(tag, "format") {
        None | Some("ascii") if !tag.ends_with("/>") => {
            let value: f64 = text_after()?.split_whitespace().next()?.parse().ok()?;
            return value.is_finite().then_some(value);
        }
        Some("binary") if !tag.ends_with("/>") => {
            decode_array(Payload::Base64(text_after()?.as_bytes()), header_u64, zlib, width).ok()?
        }
        Some("appended") => {
            let offset: u64 = attribute(tag, "offset")?.parse().ok()?;
            let xml_end = xml_end?;
            let tail = &head[xml_end..];
            let tag_end = find(tail, b">")?;
            let encoding = attribute(std::str::from_utf8(&tail[..=tag_end]).ok()?, "encoding")?.to_string();
            let data_start = (xml_end + tag_end + find(&tail[tag_end..], b"_")? + 1) as u64;
            // The value's block: a header and one value, compressed or encoded, in a few bytes.
            let mut block = Vec::new();
            file.seek(SeekFrom::Start(data_start + offset)).ok()?;
            file.take(4096).read_to_end(&mut block).ok()?;
            let payload = match encoding.as_str() {
                "raw" => Payload::Raw(&block),
                // The arrays' texts follow one another: this one's ends where its lengths say.
                "base64" => Payload::Base64(&block[..base64_len(&block, header_u64, zlib, width)?]),
                _ => return None,
            };
            decode_array(payload, header_u64, zlib, width).ok()?
        }
        _ => return None,
    };
    let b = bytes.get(..width)?;
    let value = match (kind, width) {
        ('f', 8) => f64::from_le_bytes(b.try_into().ok()?),
        ('f', _) => f64::from(f32::from_le_bytes(b.try_into().ok()?)),
        ('i', 8) => i64::from_le_bytes(b.try_into().ok()?) as f64,
        ('i', _) => f64::from(i32::from_le_bytes(b.try_into().ok()?)),
        ('u', 8) => u64::from_le_bytes(b.try_into().ok()?) as f64,
        _ => f64::from(u32::from_le_bytes(b.try_into().ok()?)),
    };
    value.is_finite().then_some(value)
}

/// The characters of the appended base64 text `text` (no whitespace, as VTK writes it) that
/// encode the array at its start, of `want` bytes uncompressed: its header and data as one
/// text, or with zlib its header's text and then its blocks'.
fn base64_len(text: &[u8], header_u64: bool, zlib: bool, want: usize) -> Option<usize> {
    use base64::Engine;
    let hlen = if header_u64 { 8 } else { 4 };
    let chars_for = |bytes: usize| bytes.div_ceil(3) * 4;
    if !zlib {
        return Some(chars_for(hlen + want)).filter(|&n| n <= text.len());
    }
    let decode = |n: usize| base64::engine::general_purpose::STANDARD.decode(text.get(..chars_for(n))?).ok();
    let word = |b: &[u8], k: usize| -> Option<usize> {
        let b = b.get(k * hlen..(k + 1) * hlen)?;
        let v = if header_u64 {
            u64::from_le_bytes(b.try_into().ok()?)
        } else {
            u64::from(u32::from_le_bytes(b.try_into().ok()?))
        };
        usize::try_from(v).ok()
    };
    let count = word(&decode(hlen)?, 0)?;
    let size = hlen.checked_mul(count.checked_add(3)?)?;
    let header = decode(size)?;
    let compressed = (0..count).try_fold(0usize, |sum, k| sum.checked_add(word(&header, 3 + k)?))?;
    Some(chars_for(size) + chars_for(compressed)).filter(|&n| n <= text.len())
}

/// Where the last `needle` in `haystack` starts.
fn rfind(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).rposition(|w| w == needle)
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

/// The JSON sidecar of a raw volume.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSidecar {
    /// `[nx, ny, nz]`.
    dims: [usize; 3],
    aabb: [[f64; 3]; 2],
    spacing: [f64; 3],
    dtype: String,
    order: String,
    /// The instant of a time-resolved field the volume holds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    time: Option<f64>,
}

/// The sidecar path of a raw volume: `<path>.json` (e.g. `field.raw.json`).
pub fn raw_sidecar_path(path: &Path) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(".json");
    PathBuf::from(s)
}

/// Writes little-endian f32 values, x fastest, to `path` and the sidecar
/// [`raw_sidecar_path`]`(path)` describing them (see the module docs).
pub fn write_raw(path: &Path, volume: &Volume) -> Result<(), IoError> {
    write_raw_at(path, volume, None)
}

/// [`write_raw`], recording in the sidecar the instant `time` a volume of a time-resolved field
/// holds (its `time`, which [`raw_time`] reads back).
pub fn write_raw_at(path: &Path, volume: &Volume, time: Option<f64>) -> Result<(), IoError> {
    let sp = volume.spacing();
    let sidecar = RawSidecar {
        dims: volume.dims,
        aabb: [volume.aabb.min.to_array(), volume.aabb.max.to_array()],
        spacing: sp.to_array(),
        dtype: "<f4".into(),
        order: "x fastest: index (k * ny + j) * nx + i".into(),
        time,
    };
    let json_path = raw_sidecar_path(path);
    let json = serde_json::to_string_pretty(&sidecar)
        .map_err(|e| IoError::Json { path: json_path.clone(), error: e.to_string() })?;
    // Both complete before either replaces an earlier pair: the volume written and its sidecar
    // not (a full disk) left new data beside the earlier sidecar, read with its grid and box.
    crate::atomic_write_together(vec![
        (json_path.as_path(), Box::new(|w: &mut dyn Write| w.write_all(json.as_bytes()))),
        (path, Box::new(|w: &mut dyn Write| write_f32_le(w, &volume.data))),
    ])
}

/// Refuses a volume read from `path` that holds a NaN or infinite voxel, naming the first.
pub fn check_finite(path: &Path, volume: &Volume) -> Result<(), IoError> {
    match volume.data.iter().position(|x| !x.is_finite()) {
        Some(i) => Err(IoError::NonFinite { path: path.into(), location: format!("voxel {i}"), value: volume.data[i] }),
        None => Ok(()),
    }
}

/// The instant the sidecar of the raw volume `path` records (`time`); None when it records
/// none or cannot be read.
pub fn raw_time(path: &Path) -> Option<f64> {
    let text = std::fs::read_to_string(raw_sidecar_path(path)).ok()?;
    serde_json::from_str::<RawSidecar>(&text).ok()?.time.filter(|t| t.is_finite())
}

/// Reads a raw volume written by [`write_raw`] (its sidecar must sit next to it).
pub fn read_raw(path: &Path) -> Result<Volume, IoError> {
    let json_path = raw_sidecar_path(path);
    let text = crate::read_input_text(&json_path, "raw volume sidecar")?;
    let meta: RawSidecar = serde_json::from_str(&text).map_err(|e| IoError::json(&json_path, &text, &e))?;
    if meta.dtype != "<f4" {
        return Err(IoError::invalid(&json_path, format!("dtype {} is not supported (only <f4)", meta.dtype)));
    }
    // The values are read x fastest over the box: a sidecar saying otherwise describes another
    // volume than the one read.
    if !meta.order.starts_with("x fastest") {
        return Err(IoError::invalid(
            &json_path,
            format!("order {:?} is not supported (only \"x fastest: index (k * ny + j) * nx + i\")", meta.order),
        ));
    }
    let aabb = Aabb { min: DVec3::from_array(meta.aabb[0]), max: DVec3::from_array(meta.aabb[1]) };
    aabb.validate().map_err(|e| IoError::invalid(&json_path, e.to_string()))?;
    if meta.dims.contains(&0) {
        return Err(IoError::invalid(&json_path, "dims must be positive"));
    }
    let spacing = aabb.size() / DVec3::from_array(meta.dims.map(|d| d as f64));
    let given = DVec3::from_array(meta.spacing);
    if (given - spacing).abs().cmpgt(spacing * 1e-6).any() || !given.is_finite() {
        return Err(IoError::invalid(
            &json_path,
            format!(
                "spacing {} is not the box's size over dims {:?}, {}: the sidecar describes two volumes",
                fluidnerf_core::num(meta.spacing),
                meta.dims,
                fluidnerf_core::num(spacing.to_array().map(|h| (h * 1e9).round() / 1e9))
            ),
        ));
    }
    let needed = meta.dims.iter().try_fold(4usize, |acc, &d| acc.checked_mul(d));
    let Some(needed) = needed else {
        return Err(IoError::invalid(&json_path, format!("dims {:?}: more voxels than a volume can hold", meta.dims)));
    };
    let bytes = crate::read_input(path, "raw volume")?;
    if bytes.len() != needed {
        return Err(IoError::invalid(path, format!("{} bytes, but dims {:?} need {needed}", bytes.len(), meta.dims)));
    }
    let data = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    Ok(Volume::from_vec(meta.dims, aabb, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_volume() -> Volume {
        let aabb = Aabb::new(DVec3::new(-1.0, 2.0, 0.5), DVec3::new(3.0, 4.5, 1.7));
        Volume::from_fn([5, 4, 3], aabb, |p| (p.x * 10.0 + p.y * 3.0 - p.z) as f32)
    }

    #[test]
    fn npy_round_trip_and_shape_order() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.npy");
        let v = test_volume();
        write_npy(&p, &v).expect("write");
        let back = read_npy(&p, v.aabb).expect("read");
        assert_eq!(back, v);
        let bytes = std::fs::read(&p).expect("bytes");
        let npy = npyz::NpyFile::new(&bytes[..]).expect("npy");
        assert_eq!(npy.shape(), &[3, 4, 5], "(nz, ny, nx)");
        assert_eq!(npy.dtype().descr(), "'<f4'");
    }

    fn write_npy_with<T: npyz::Serialize + npyz::AutoSerialize + Copy>(
        p: &Path,
        shape: &[u64],
        data: &[T],
        order: npyz::Order,
    ) {
        let mut f = std::fs::File::create(p).expect("create");
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(shape)
            .order(order)
            .writer(&mut f)
            .begin_nd()
            .expect("begin");
        w.extend(data.iter().copied()).expect("extend");
        w.finish().expect("finish");
    }

    /// A file cut short, even by less than its header's length, is refused before it is read,
    /// with how much data its shape needs and how much there is.
    #[test]
    fn a_truncated_npy_says_how_much_data_is_missing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.npy");
        let v = test_volume();
        write_npy(&p, &v).expect("write");
        let bytes = std::fs::read(&p).expect("bytes");
        for cut in [4, 100] {
            std::fs::write(&p, &bytes[..bytes.len() - cut]).expect("truncates");
            let err = read_npy(&p, v.aabb).expect_err("truncated").to_string();
            let needed =
                format!("shape [3, 4, 5] of '<f4' needs 240 bytes of data, but {} follow the header", 240 - cut);
            assert!(err.contains(&needed) && err.contains("v.npy"), "{err}");
        }
        let p2 = dir.path().join("v2.npy");
        write_npy_with(&p2, &[1, 1, 2], &[1f32, 2.0], npyz::Order::C);
        assert_eq!(npy_data_offset(&std::fs::read(&p2).expect("bytes")) % 64, 0, "headers are padded to 64 bytes");
    }

    #[test]
    fn npy_accepts_other_dtypes_and_rejects_bad_layouts() {
        let dir = tempfile::tempdir().expect("tempdir");
        let aabb = Aabb::cube(DVec3::ZERO, 1.0);
        let p = dir.path().join("u16.npy");
        write_npy_with(&p, &[1, 2, 3], &[0u16, 1, 2, 3, 4, 65535], npyz::Order::C);
        let v = read_npy(&p, aabb).expect("u16");
        assert_eq!(v.dims, [3, 2, 1]);
        assert_eq!(v.data, vec![0.0, 1.0, 2.0, 3.0, 4.0, 65535.0]);
        let p = dir.path().join("f64.npy");
        write_npy_with(&p, &[1, 1, 2], &[0.25f64, -2.0], npyz::Order::C);
        assert_eq!(read_npy(&p, aabb).expect("f64").data, vec![0.25, -2.0]);
        let p = dir.path().join("u8.npy");
        write_npy_with(&p, &[1, 1, 2], &[7u8, 255], npyz::Order::C);
        assert_eq!(read_npy(&p, aabb).expect("u8").data, vec![7.0, 255.0]);
        // Fortran order: element [k, j, i] of shape (2, 3, 4) stored at k + 2 (j + 3 i), with the
        // value 100 k + 10 j + i, must read as voxel (i, j, k) = 100 k + 10 j + i.
        let p = dir.path().join("fortran.npy");
        let mut stored = vec![0f32; 24];
        for k in 0..2 {
            for j in 0..3 {
                for i in 0..4 {
                    stored[k + 2 * (j + 3 * i)] = (100 * k + 10 * j + i) as f32;
                }
            }
        }
        write_npy_with(&p, &[2, 3, 4], &stored, npyz::Order::Fortran);
        let v = read_npy(&p, aabb).expect("fortran");
        assert_eq!(v.dims, [4, 3, 2]);
        for k in 0..2 {
            for j in 0..3 {
                for i in 0..4 {
                    assert_eq!(v.data[v.index(i, j, k)], (100 * k + 10 * j + i) as f32, "voxel ({i}, {j}, {k})");
                }
            }
        }
        let p = dir.path().join("flat.npy");
        write_npy_with(&p, &[4, 2], &[0f32; 8], npyz::Order::C);
        let err = read_npy(&p, aabb).expect_err("2-D");
        assert!(err.to_string().contains("3-D") && err.to_string().contains("[4, 2]"), "{err}");
        let p = dir.path().join("i32.npy");
        write_npy_with(&p, &[1, 1, 2], &[1i32, 2], npyz::Order::C);
        assert!(read_npy(&p, aabb).expect_err("i32").to_string().contains("dtype"));
    }

    #[test]
    fn vti_round_trip_and_origin_at_first_voxel_centre() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.vti");
        let v = test_volume();
        write_vti(&p, &v).expect("write");
        let back = read_vti(&p).expect("read");
        assert_eq!(back.dims, v.dims);
        assert_eq!(back.data, v.data);
        for a in 0..3 {
            assert!((back.aabb.min[a] - v.aabb.min[a]).abs() < 1e-12);
            assert!((back.aabb.max[a] - v.aabb.max[a]).abs() < 1e-12);
        }
        let text = String::from_utf8_lossy(&std::fs::read(&p).expect("bytes")).into_owned();
        let c = v.voxel_centre(0, 0, 0);
        assert!(text.contains(&format!("Origin=\"{} {} {}\"", c.x, c.y, c.z)), "{}", &text[..400]);
        assert!(text.contains("WholeExtent=\"0 4 0 3 0 2\""));
    }

    #[test]
    fn a_volumes_instant_is_recorded_in_its_vti_and_raw_sidecar() {
        let dir = tempfile::tempdir().expect("tempdir");
        let v = test_volume();
        let (timed, plain) = (dir.path().join("t.vti"), dir.path().join("p.vti"));
        write_vti_at(&timed, &v, Some(16.5)).expect("write");
        write_vti(&plain, &v).expect("write");
        assert_eq!(read_vti(&timed).expect("the time is not a second array"), read_vti(&plain).expect("read"));
        assert_eq!((vti_time(&timed), vti_time(&plain)), (Some(16.5), None));
        // An instant that is no short decimal reads back to the same f64.
        write_vti_at(&timed, &v, Some(0.1 + 0.2)).expect("write");
        assert_eq!(vti_time(&timed), Some(0.1 + 0.2));
        // A file of another writer: field data before the piece, one point array and no
        // `Scalars` naming it, a time in ASCII.
        let other = dir.path().join("o.vti");
        std::fs::write(
            &other,
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\">\n\
             <ImageData WholeExtent=\"0 1 0 0 0 0\" Origin=\"0 0 0\" Spacing=\"1 1 1\">\n\
             <FieldData><DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" format=\"ascii\">\n\
             2.25\n</DataArray></FieldData>\n<Piece Extent=\"0 1 0 0 0 0\"><PointData>\n\
             <DataArray type=\"Float32\" Name=\"e\" format=\"ascii\">1 2</DataArray>\n\
             </PointData></Piece></ImageData></VTKFile>\n",
        )
        .expect("write");
        assert_eq!(read_vti(&other).expect("read").data, vec![1.0, 2.0]);
        assert_eq!(vti_time(&other), Some(2.25));

        let (timed, plain) = (dir.path().join("t.raw"), dir.path().join("p.raw"));
        write_raw_at(&timed, &v, Some(-3.0)).expect("write");
        write_raw(&plain, &v).expect("write");
        assert_eq!(read_raw(&timed).expect("read"), v);
        assert_eq!((raw_time(&timed), raw_time(&plain)), (Some(-3.0), None));
        let sidecar = std::fs::read_to_string(raw_sidecar_path(&plain)).expect("sidecar");
        assert!(!sidecar.contains("time"), "a volume fixed in time records none: {sidecar}");
    }

    #[test]
    fn vti_ascii_and_bad_files() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.vti");
        std::fs::write(
            &p,
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"ImageData\" version=\"0.1\" byte_order=\"LittleEndian\">\n\
             <ImageData WholeExtent=\"0 1 0 0 0 0\" Origin=\"0.5 0 0\" Spacing=\"1 2 3\">\n<Piece Extent=\"0 1 0 0 0 0\">\n\
             <PointData><DataArray type=\"Float64\" Name=\"v\" format=\"ascii\">1.5 -2</DataArray></PointData>\n\
             </Piece></ImageData></VTKFile>\n",
        )
        .expect("write");
        let v = read_vti(&p).expect("ascii");
        assert_eq!(v.dims, [2, 1, 1]);
        assert_eq!(v.data, vec![1.5, -2.0]);
        assert_eq!(v.aabb.min, DVec3::new(0.0, -1.0, -1.5));
        assert_eq!(v.aabb.max, DVec3::new(2.0, 1.0, 1.5));
        std::fs::write(&p, "<VTKFile type=\"PolyData\">").expect("write");
        let err = read_vti(&p).expect_err("polydata").to_string();
        assert!(err.contains("a.vti") && err.contains("ImageData"), "{err}");
        // Extents whose voxel count overflows, or exceeds what a volume holds, are refused.
        for extent in
            ["0 4611686018427387904 0 3 0 0", "-9223372036854775806 9223372036854775806 0 0 0 0", "0 65535 0 65536 0 0"]
        {
            let text = format!(
                "<VTKFile type=\"ImageData\"><ImageData WholeExtent=\"{extent}\" Origin=\"0 0 0\" Spacing=\"1 1 1\">\
                 <Piece><PointData><DataArray type=\"Float32\" format=\"ascii\">1 1</DataArray></PointData></Piece>\
                 </ImageData></VTKFile>"
            );
            std::fs::write(&p, text).expect("write");
            let err = read_vti(&p).expect_err(extent).to_string();
            assert!(err.contains("a.vti") && err.contains("WholeExtent"), "{extent}: {err}");
        }
        // A missing or malformed extent, origin or spacing is named with what is wrong: the
        // error said only `WholeExtent`, even of an extent past the range of whole numbers.
        for (image, expected) in [
            (
                "WholeExtent=\"0 18446744073709551615 0 0 0 0\" Origin=\"0 0 0\" Spacing=\"1 1 1\"",
                "WholeExtent must be 6 whole numbers, got \"0 18446744073709551615 0 0 0 0\"",
            ),
            ("Origin=\"0 0 0\" Spacing=\"1 1 1\"", "<ImageData> has no WholeExtent"),
            ("WholeExtent=\"0 1 0 0 0 0\" Origin=\"0 0\" Spacing=\"1 1 1\"", "Origin must be 3 numbers, got \"0 0\""),
            (
                "WholeExtent=\"0 1 0 0 0 0\" Origin=\"0 0 0\" Spacing=\"1 x 1\"",
                "Spacing must be 3 numbers, got \"1 x 1\"",
            ),
            // A Direction of commas was taken as the identity, whatever axes it named.
            (
                "WholeExtent=\"0 1 0 0 0 0\" Origin=\"0 0 0\" Spacing=\"1 1 1\" Direction=\"0,1,0,1,0,0,0,0,1\"",
                "Direction must be 9 numbers, got \"0,1,0,1,0,0,0,0,1\"",
            ),
        ] {
            let text = format!(
                "<VTKFile type=\"ImageData\"><ImageData {image}><Piece><PointData><DataArray type=\"Float32\" \
                 format=\"ascii\">1 1</DataArray></PointData></Piece></ImageData></VTKFile>"
            );
            std::fs::write(&p, text).expect("write");
            let err = read_vti(&p).expect_err(image).to_string();
            assert!(err.contains("a.vti") && err.contains(expected), "{image}: {err}");
        }
    }

    /// Cell data, as finite-volume solvers write it, is a voxel per cell, filling the extent's
    /// box; point data is a voxel per point, in the box around them, placed by where the
    /// extent starts (both were read as point data from index 0: cell data refused for its
    /// count, an extent from 10 placed ten spacings off).
    #[test]
    fn vti_cell_data_and_extents_that_do_not_start_at_zero() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("cells.vti");
        let write = |extent: &str, data: &str| {
            let text = format!(
                r#"<VTKFile type="ImageData" byte_order="LittleEndian"><ImageData WholeExtent="{extent}" Origin="1 0 0" Spacing="2 1 1"><Piece>{data}</Piece></ImageData></VTKFile>"#
            );
            std::fs::write(&p, text).expect("write");
        };
        // Three points along x, so two cells; one cell along y and z.
        let cells = r#"<PointData/><CellData Scalars="smoke"><DataArray type="Float32" Name="smoke" format="ascii">0.25 0.75</DataArray></CellData>"#;
        write("0 2 0 1 0 1", cells);
        let v = read_vti(&p).expect("cell data");
        assert_eq!((v.dims, v.data.clone()), ([2, 1, 1], vec![0.25, 0.75]));
        assert_eq!((v.aabb.min, v.aabb.max), (DVec3::new(1.0, 0.0, 0.0), DVec3::new(5.0, 1.0, 1.0)));
        write("10 12 0 1 0 1", cells);
        let v = read_vti(&p).expect("cell data");
        assert_eq!((v.aabb.min, v.aabb.max), (DVec3::new(21.0, 0.0, 0.0), DVec3::new(25.0, 1.0, 1.0)));
        let points = r#"<CellData/><PointData><DataArray type="Float32" format="ascii">1 2</DataArray></PointData>"#;
        write("10 11 0 0 0 0", points);
        let v = read_vti(&p).expect("point data");
        assert_eq!((v.aabb.min, v.aabb.max), (DVec3::new(20.0, -0.5, -0.5), DVec3::new(24.0, 0.5, 0.5)));
        write("0 2 0 0 0 1", cells);
        let err = read_vti(&p).expect_err("no cells").to_string();
        assert!(err.contains("cells.vti") && err.contains("holds no cells"), "{err}");
    }

    /// Of several arrays, the one `<PointData Scalars>` names is read, not the first; without
    /// that name, several arrays are refused, listed.
    #[test]
    fn vti_with_several_arrays_reads_the_named_one() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("two.vti");
        let write = |point_data: &str| {
            let text = format!(
                "<VTKFile type=\"ImageData\" byte_order=\"LittleEndian\"><ImageData WholeExtent=\"0 1 0 0 0 0\" \
                 Origin=\"0 0 0\" Spacing=\"1 1 1\"><Piece>{point_data}\
                 <DataArray type=\"Float32\" Name=\"mask\" format=\"ascii\">1 1</DataArray>\
                 <DataArray type=\"Float32\" Name=\"density\" format=\"ascii\">0.5 2</DataArray>\
                 </PointData></Piece></ImageData></VTKFile>"
            );
            std::fs::write(&p, text).expect("write");
        };
        write("<PointData Scalars=\"density\">");
        assert_eq!(read_vti(&p).expect("the named array").data, vec![0.5, 2.0]);
        write("<PointData>");
        let err = read_vti(&p).expect_err("which array").to_string();
        assert!(err.contains("two.vti") && err.contains("2 data arrays (mask, density)"), "{err}");
        write("<PointData Scalars=\"speed\">");
        let err = read_vti(&p).expect_err("no such array").to_string();
        assert!(err.contains("two.vti") && err.contains("Scalars=\"speed\"> names no <DataArray>"), "{err}");
    }

    /// An appended block is read by its length header and its array's offset: a block cut
    /// short, a header that disagrees with the extent, an offset past the end of the file (or
    /// of the address space: it wrapped round to the XML) and a block that runs into the next
    /// array's are refused naming the file and the array.
    #[test]
    fn vti_appended_blocks_that_do_not_fit_are_refused_naming_the_array() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("b.vti");
        let write = |arrays: &str, data: &[u8]| {
            let mut bytes = format!(
                "<VTKFile type=\"ImageData\" byte_order=\"LittleEndian\" header_type=\"UInt64\"><ImageData \
                 WholeExtent=\"0 1 0 0 0 0\" Origin=\"0 0 0\" Spacing=\"1 1 1\"><Piece><PointData Scalars=\"v\">\
                 {arrays}</PointData></Piece></ImageData><AppendedData encoding=\"raw\">_"
            )
            .into_bytes();
            bytes.extend_from_slice(data);
            bytes.extend_from_slice(b"</AppendedData></VTKFile>");
            std::fs::write(&p, bytes).expect("write");
        };
        let array = |name: &str, offset: &str| {
            format!("<DataArray type=\"Float32\" Name=\"{name}\" format=\"appended\" offset=\"{offset}\"/>")
        };
        let block = |len: u64, values: &[f32]| {
            let mut b = len.to_le_bytes().to_vec();
            values.iter().for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
            b
        };
        write(&array("v", "0"), &block(8, &[1.0, 2.0]));
        assert_eq!(read_vti(&p).expect("a good block").data, vec![1.0, 2.0]);
        let refused = |needle: &str| {
            let err = read_vti(&p).expect_err(needle).to_string();
            assert!(err.contains("b.vti") && err.contains("array \"v\"") && err.contains(needle), "{err}");
        };
        // Cut short: the header says 8 bytes, 4 follow before the end of the file.
        let mut short = block(8, &[1.0]);
        std::fs::write(&p, []).expect("write");
        write(&array("v", "0"), &short);
        refused("its appended block");
        short.truncate(4);
        write(&array("v", "0"), &short);
        refused("its appended block");
        write(&array("v", "0"), &block(12, &[1.0, 2.0, 3.0]));
        refused("holds 12 bytes, the extent needs 8");
        for offset in ["1000", "18446744073709551615", "18446744073709551000"] {
            write(&array("v", offset), &block(8, &[1.0, 2.0]));
            refused("offset");
        }
        // Two arrays whose blocks overlap: v's header claims the bytes of w's block.
        let two = format!("{}{}", array("v", "0"), array("w", "12"));
        let mut data = block(8, &[1.0, 2.0]);
        data.extend(block(8, &[3.0, 4.0]));
        write(&two, &data);
        refused("runs into the block of array \"w\" at offset 12");
        let two = format!("{}{}", array("v", "0"), array("w", "16"));
        write(&two, &data);
        assert_eq!(read_vti(&p).expect("blocks one after the other").data, vec![1.0, 2.0]);
    }

    #[test]
    fn raw_round_trip_with_sidecar() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v.raw");
        let v = test_volume();
        write_raw(&p, &v).expect("write");
        assert_eq!(std::fs::metadata(&p).expect("meta").len(), 4 * 60);
        let side: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("v.raw.json")).expect("sidecar"))
                .expect("json");
        assert_eq!(side["dims"], serde_json::json!([5, 4, 3]));
        assert_eq!(read_raw(&p).expect("read"), v);
        // A sidecar whose dims overflow is refused, naming it.
        let sidecar = dir.path().join("v.raw.json");
        let mut meta = side;
        meta["dims"] = serde_json::json!([4294967296u64, 4294967296u64, 1]);
        std::fs::write(&sidecar, meta.to_string()).expect("write");
        let err = read_raw(&p).expect_err("overflowing dims").to_string();
        assert!(err.contains("v.raw.json") && err.contains("dims"), "{err}");
        // A sidecar of another order, or whose spacing is not its box's over its dims, was read
        // as x fastest over the box without a word.
        meta["dims"] = serde_json::json!([5, 4, 3]);
        meta["order"] = serde_json::json!("z fastest");
        std::fs::write(&sidecar, meta.to_string()).expect("write");
        let err = read_raw(&p).expect_err("another order").to_string();
        assert!(
            err.contains("v.raw.json") && err.contains("order \"z fastest\" is not supported (only \"x fastest"),
            "{err}"
        );
        meta["order"] = serde_json::json!("x fastest: index (k * ny + j) * nx + i");
        meta["spacing"] = serde_json::json!([1.0, 1.0, 1.0]);
        std::fs::write(&sidecar, meta.to_string()).expect("write");
        let err = read_raw(&p).expect_err("another spacing").to_string();
        assert!(
            err.contains("v.raw.json")
                && err.contains("spacing [1, 1, 1] is not the box's size over dims [5, 4, 3], [0.8, 0.625, 0.4]"),
            "{err}"
        );
    }

    #[test]
    fn cells_far_from_cubic_are_named_and_grids_made_for_the_box_are_not() {
        use fluidnerf_core::glam::DVec3;
        let cube = Aabb::new(DVec3::splat(-20.0), DVec3::splat(20.0));
        let why = uneven_cells([32, 32, 16], &cube).expect("half the slices over the whole box");
        assert!(why.contains("32×32×16") && why.contains("1.2500×1.2500×2.5000"), "{why}");
        assert!(uneven_cells([32, 32, 32], &cube).is_none());
        for (size, longest) in
            [(DVec3::new(3.0, 1.0, 0.5), 7), (DVec3::new(1.0, 0.75, 0.3), 5), (DVec3::new(2.0, 2.0, 0.1), 64)]
        {
            let aabb = Aabb::new(DVec3::ZERO, size);
            let dims = Volume::dims_for(&aabb, longest);
            assert!(uneven_cells(dims, &aabb).is_none(), "{dims:?} for {size}");
        }
        // A flat grid (one cell across) has no cubic shape to keep.
        assert!(uneven_cells([32, 32, 1], &cube).is_none());
    }

    /// A `.npy` of version 2 (a 4-byte header length, as NumPy writes for long headers) reads,
    /// and one cut short says by how much from where its data begin.
    #[test]
    fn an_npy_of_version_2_is_read_past_its_longer_header_length() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("v2.npy");
        let mut header = "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 1, 3), }".to_string();
        while !(12 + header.len() + 1).is_multiple_of(64) {
            header.push(' ');
        }
        header.push('\n');
        let mut bytes = b"\x93NUMPY\x02\x00".to_vec();
        bytes.extend((header.len() as u32).to_le_bytes());
        bytes.extend(header.as_bytes());
        assert_eq!(npy_data_offset(&bytes), bytes.len());
        for v in [1.5f32, -2.0, 8.25] {
            bytes.extend(v.to_le_bytes());
        }
        std::fs::write(&p, &bytes).expect("write");
        let aabb = Aabb::cube(DVec3::ZERO, 1.0);
        assert_eq!(read_npy(&p, aabb).expect("version 2").data, vec![1.5, -2.0, 8.25]);
        std::fs::write(&p, &bytes[..bytes.len() - 2]).expect("write");
        let e = read_npy(&p, aabb).expect_err("cut").to_string();
        assert!(e.contains("needs 12 bytes of data, but 10 follow the header"), "{e}");
        // Too short to hold its header's length: all of it is taken for header.
        assert_eq!(npy_data_offset(b"\x93NUMPY\x01\x00\x10"), usize::MAX);
        assert_eq!(npy_data_offset(b"\x93NUMPY\x01\x00\x10\x00"), 10 + 16);
        assert_eq!(npy_data_offset(b"\x93NUMPY\x02\x00\x10\x00\x00\x01"), 12 + 16 + (1 << 24));
    }

    /// Cells up to 1.5 times longer on one axis than another are taken as cubic enough.
    #[test]
    fn cells_up_to_half_again_as_long_pass_without_a_word() {
        let aabb = Aabb::new(DVec3::ZERO, DVec3::new(15.0, 10.0, 10.0));
        assert!(uneven_cells([10, 10, 10], &aabb).is_none(), "1.5 against 1");
        assert!(uneven_cells([9, 10, 10], &aabb).is_some(), "1.67 against 1");
        assert!(uneven_cells([10, 9, 10], &Aabb::new(DVec3::ZERO, DVec3::new(10.0, 15.0, 10.0))).is_some());
        assert!(uneven_cells([10, 10, 6], &Aabb::new(DVec3::ZERO, DVec3::splat(10.0))).is_some(), "z too");
    }

    /// Every data mode of VTK's own writer (`tests/fixtures/vti/make_vti_variants.py`: ASCII,
    /// inline base64, appended base64 and raw, each uncompressed and zlib-compressed in one
    /// block and in several, with 32- and 64-bit headers) reads as the same volume. Only raw
    /// uncompressed was read before: ParaView's and pyvista's defaults (appended, zlib) were
    /// refused, and so was VTK's ASCII, whose file names a compressor.
    #[test]
    fn vti_files_in_every_mode_of_vtks_writer_read_as_one_volume() {
        let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/vti");
        let mut names: Vec<PathBuf> = std::fs::read_dir(&folder)
            .expect("the fixtures")
            .map(|e| e.expect("entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "vti"))
            .collect();
        names.sort();
        assert_eq!(names.len(), 24 + 16, "4 modes × 3 compressions × 2 headers; 4 × 2 × 2 kinds of time");
        let expected: Vec<f32> =
            (0..3).flat_map(|k| (0..4).flat_map(move |j| (0..5).map(move |i| (i + 10 * j + 100 * k) as f32))).collect();
        for path in names {
            // The instant ParaView stores, after another field array, in every mode; none in the
            // files without one.
            let name = path.file_name().and_then(|n| n.to_str()).expect("a name");
            let time = match (name.starts_with("timed_float32_"), name.starts_with("timed_")) {
                (true, _) => Some(16.25),
                (false, true) => Some(16.5),
                _ => None,
            };
            assert_eq!(vti_time(&path), time, "{}", path.display());
            let v = read_vti(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!(v.dims, [5, 4, 3], "{}", path.display());
            assert_eq!(v.data, expected, "{}", path.display());
            let (min, max) = (v.aabb.min.to_array(), v.aabb.max.to_array());
            for (got, want) in min.iter().chain(&max).zip([-1.0, 2.0, 0.5, 3.0, 4.5, 1.7]) {
                assert!((got - want).abs() < 1e-12, "{}: box {min:?}..{max:?}", path.display());
            }
        }
    }

    /// A compressed block that does not inflate to its stated size, and a compressor other than
    /// zlib, are refused naming the array and the problem.
    #[test]
    fn vti_compressed_arrays_that_do_not_fit_are_refused() {
        let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/vti");
        let dir = tempfile::tempdir().expect("tempdir");
        let text = std::fs::read_to_string(folder.join("binary_zlib_uint32.vti")).expect("fixture");
        let lz4 = dir.path().join("lz4.vti");
        std::fs::write(&lz4, text.replace("vtkZLibDataCompressor", "vtkLZ4DataCompressor")).expect("writes");
        let e = read_vti(&lz4).expect_err("LZ4").to_string();
        assert!(e.contains("compressor vtkLZ4DataCompressor: only zlib"), "{e}");
        // The extent grown by a slice: the blocks hold 240 bytes where 320 are needed.
        let grown = dir.path().join("grown.vti");
        std::fs::write(&grown, text.replace("WholeExtent=\"0 4 0 3 0 2\"", "WholeExtent=\"0 4 0 3 0 3\""))
            .expect("writes");
        let e = read_vti(&grown).expect_err("a larger extent").to_string();
        assert!(e.contains("array \"value\": its 1 compressed blocks hold 240 bytes, the extent needs 320"), "{e}");
        // A base64 text cut short.
        let raw = std::fs::read_to_string(folder.join("binary_none_uint32.vti")).expect("fixture");
        let start = raw.find("8AAAAA").expect("the array's text");
        let cut = dir.path().join("cut.vti");
        std::fs::write(&cut, format!("{}{}", &raw[..start + 40], &raw[start + 200..])).expect("writes");
        let e = read_vti(&cut).expect_err("cut short").to_string();
        assert!(e.contains("array \"value\": "), "{e}");
    }
}
