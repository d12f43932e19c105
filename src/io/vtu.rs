//! VTK XML unstructured grids (`.vtu`).
//!
//! Writing: a mesh of tetrahedra only as `VTK_TETRA` (10) cells; any other
//! mesh with every element as `VTK_POLYHEDRON` (42) with the
//! `faces`/`faceoffsets` arrays, so any element cleave makes opens in
//! ParaView (readers such as meshio do not accept polyhedra mixed with other
//! cell types, hence all or nothing). Arrays are base64 `binary` with a UInt64
//! header. Reading: `VTK_TETRA`, `VTK_HEXAHEDRON` (12) and `VTK_POLYHEDRON`
//! cells from `ascii` or uncompressed `binary` arrays.

use std::fmt::Write;
use std::path::Path;

use base64::Engine;
use quick_xml::events::Event;

use super::{read_text, write_text, IoError};
use crate::mesh::{Cell, PolyMesh};

const VTK_TETRA: u8 = 10;
const VTK_HEXAHEDRON: u8 = 12;
const VTK_POLYHEDRON: u8 = 42;

/// Point and cell data written with a mesh.
#[derive(Default)]
pub struct VtuFields<'a> {
    /// Per-node 3-vectors (e.g. `displacement` in m, `velocity` in m/s).
    pub point_vectors: Vec<(&'a str, &'a [[f64; 3]])>,
    /// Per-element scalars (e.g. `von_mises` in Pa).
    pub cell_scalars: Vec<(&'a str, &'a [f64])>,
    /// Per-element integers (e.g. `vertex_count`; `element_id` is always written).
    pub cell_ints: Vec<(&'a str, &'a [i64])>,
}

fn b64<T: bytemuck::Pod>(data: &[T]) -> String {
    let bytes: &[u8] = bytemuck::cast_slice(data);
    let mut buf = Vec::with_capacity(8 + bytes.len());
    buf.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
    buf.extend_from_slice(bytes);
    base64::engine::general_purpose::STANDARD.encode(buf)
}

fn data_array(s: &mut String, ty: &str, name: &str, comps: usize, payload: String) {
    // scalar arrays carry no NumberOfComponents, as VTK writes them (meshio
    // would otherwise read them as n x 1 tables)
    let comps = if comps == 1 { String::new() } else { format!(" NumberOfComponents=\"{comps}\"") };
    let _ =
        writeln!(s, "        <DataArray type=\"{ty}\" Name=\"{name}\"{comps} format=\"binary\">{payload}</DataArray>");
}

/// Writes `mesh` with node positions `points` (m; pass the rest positions or
/// the deformed ones) and the given fields (cell fields in element order).
///
/// Polyhedral cells are written in ascending vertex count, by element index
/// within a count, with their cell fields in the same order: meshio groups
/// polyhedra by vertex count in order of first appearance but their cell
/// data by ascending count, so any other order breaks its reading. The
/// `element_id` cell field (written here) keeps the engine's numbering, and
/// [`read_vtu`] restores that order.
pub fn write_vtu(path: &Path, mesh: &PolyMesh, points: &[[f64; 3]], fields: &VtuFields) -> Result<(), IoError> {
    let mut conn: Vec<i64> = Vec::new();
    let mut offsets: Vec<i64> = Vec::with_capacity(mesh.elements.len());
    let mut types: Vec<u8> = Vec::with_capacity(mesh.elements.len());
    let mut faces: Vec<i64> = Vec::new();
    let mut faceoffsets: Vec<i64> = Vec::with_capacity(mesh.elements.len());
    let all_tets = mesh.elements.iter().all(|el| el.nodes.len() == 4 && el.faces.len() == 4);
    let mut order: Vec<usize> = (0..mesh.elements.len()).collect();
    if !all_tets {
        order.sort_by_key(|&e| mesh.elements[e].nodes.len());
    }
    for el in order.iter().map(|&e| &mesh.elements[e]) {
        if all_tets {
            let v = &el.nodes;
            let rest = |i: usize| mesh.nodes[v[i] as usize];
            let positive = cleave_kernels::tet::signed_volume(rest(0), rest(1), rest(2), rest(3)) > 0.0;
            let order = if positive { [0, 1, 2, 3] } else { [0, 2, 1, 3] };
            conn.extend(order.iter().map(|&i| v[i] as i64));
            types.push(VTK_TETRA);
        } else {
            conn.extend(el.nodes.iter().map(|&x| x as i64));
            types.push(VTK_POLYHEDRON);
            faces.push(el.faces.len() as i64);
            for r in &el.faces {
                let lp = &mesh.faces[r.face as usize].vertices;
                faces.push(lp.len() as i64);
                if r.outward {
                    faces.extend(lp.iter().map(|&x| x as i64));
                } else {
                    faces.extend(lp.iter().rev().map(|&x| x as i64));
                }
            }
            faceoffsets.push(faces.len() as i64);
        }
        offsets.push(conn.len() as i64);
    }
    let polyhedra = (!all_tets).then_some((&faces[..], &faceoffsets[..]));
    let scalars: Vec<Vec<f64>> =
        fields.cell_scalars.iter().map(|(_, v)| order.iter().map(|&e| v[e]).collect()).collect();
    let ints: Vec<Vec<i64>> = fields.cell_ints.iter().map(|(_, v)| order.iter().map(|&e| v[e]).collect()).collect();
    let ids: Vec<i64> = order.iter().map(|&e| e as i64).collect();
    let mut cell_ints: Vec<(&str, &[i64])> = vec![("element_id", &ids)];
    cell_ints.extend(fields.cell_ints.iter().zip(&ints).map(|((name, _), v)| (*name, &v[..])));
    let ordered = VtuFields {
        point_vectors: fields.point_vectors.clone(),
        cell_scalars: fields.cell_scalars.iter().zip(&scalars).map(|((name, _), v)| (*name, &v[..])).collect(),
        cell_ints,
    };
    write_cells(path, points, Cells { conn: &conn, offsets: &offsets, types: &types, polyhedra }, &ordered)
}

/// The cells of an unstructured grid: connectivity, offsets, VTK types,
/// and for polyhedra their face streams.
struct Cells<'a> {
    conn: &'a [i64],
    offsets: &'a [i64],
    types: &'a [u8],
    polyhedra: Option<(&'a [i64], &'a [i64])>,
}

/// Writes an unstructured grid of `cells` over `points` with `fields`.
fn write_cells(path: &Path, points: &[[f64; 3]], cells: Cells, fields: &VtuFields) -> Result<(), IoError> {
    let flat: Vec<f64> = points.iter().flatten().copied().collect();
    let mut s = String::new();
    s.push_str("<?xml version=\"1.0\"?>\n");
    s.push_str(
        "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n",
    );
    s.push_str("  <UnstructuredGrid>\n");
    let _ = writeln!(s, "    <Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">", points.len(), cells.types.len());
    s.push_str("      <PointData>\n");
    for (name, v) in &fields.point_vectors {
        let flat: Vec<f64> = v.iter().flatten().copied().collect();
        data_array(&mut s, "Float64", name, 3, b64(&flat));
    }
    s.push_str("      </PointData>\n      <CellData>\n");
    for (name, v) in &fields.cell_scalars {
        data_array(&mut s, "Float64", name, 1, b64(v));
    }
    for (name, v) in &fields.cell_ints {
        data_array(&mut s, "Int64", name, 1, b64(v));
    }
    s.push_str("      </CellData>\n      <Points>\n");
    data_array(&mut s, "Float64", "Points", 3, b64(&flat));
    s.push_str("      </Points>\n      <Cells>\n");
    data_array(&mut s, "Int64", "connectivity", 1, b64(cells.conn));
    data_array(&mut s, "Int64", "offsets", 1, b64(cells.offsets));
    data_array(&mut s, "UInt8", "types", 1, b64(cells.types));
    if let Some((faces, faceoffsets)) = cells.polyhedra {
        data_array(&mut s, "Int64", "faces", 1, b64(faces));
        data_array(&mut s, "Int64", "faceoffsets", 1, b64(faceoffsets));
    }
    s.push_str("      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n");
    write_text(path, &s)
}

/// Writes a ParaView collection (`.pvd`) of the VTU files `frames`
/// (time in s, file name relative to the collection), so that ParaView
/// opens the run as one time series at its real times.
pub fn write_collection(path: &Path, frames: &[(f64, String)]) -> Result<(), IoError> {
    let mut s =
        String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n  <Collection>\n");
    for (t, file) in frames {
        let _ = writeln!(s, "    <DataSet timestep=\"{t:e}\" part=\"0\" file=\"{file}\"/>");
    }
    s.push_str("  </Collection>\n</VTKFile>\n");
    write_text(path, &s)
}

/// Writes a triangle surface (VTK triangles) over `vertices` (m) with
/// per-vertex 3-vectors `point_vectors` (name, values).
pub fn write_surface_vtu(
    path: &Path,
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    point_vectors: &[(&str, &[[f64; 3]])],
) -> Result<(), IoError> {
    let conn: Vec<i64> = triangles.iter().flatten().map(|&v| v as i64).collect();
    let offsets: Vec<i64> = (1..=triangles.len() as i64).map(|t| 3 * t).collect();
    let types = vec![5u8; triangles.len()];
    let fields = VtuFields { point_vectors: point_vectors.to_vec(), ..Default::default() };
    write_cells(path, vertices, Cells { conn: &conn, offsets: &offsets, types: &types, polyhedra: None }, &fields)
}

/// One `<DataArray>` as read: its attributes and decoded numbers.
struct Array {
    name: String,
    values: Vec<f64>,
    line: usize,
}

/// Reads the cells of a `.vtu` file as a mesh.
pub fn read_vtu(path: &Path) -> Result<PolyMesh, IoError> {
    read_vtu_frame(path).map(|f| f.mesh)
}

/// A frame as cleave writes it: the cells over the file's points, the
/// `displacement` point field and the `von_mises` cell field where the file
/// has them (in the mesh's element order).
#[derive(Clone, Debug)]
pub struct VtuFrame {
    /// The cells, in the engine's element order where the file numbers
    /// them (`element_id`); nodes at the file's points.
    pub mesh: PolyMesh,
    /// Displacement of every point (m).
    pub displacement: Option<Vec<[f64; 3]>>,
    /// Von Mises stress of every element (Pa).
    pub von_mises: Option<Vec<f64>>,
}

/// Reads a VTU file with its frame fields (see [`VtuFrame`]).
pub fn read_vtu_frame(path: &Path) -> Result<VtuFrame, IoError> {
    let text = read_text(path)?;
    let line_at =
        |pos: u64| text.as_bytes()[..(pos as usize).min(text.len())].iter().filter(|&&b| b == b'\n').count() + 1;
    let mut reader = quick_xml::Reader::from_str(&text);
    let mut header64 = false;
    let mut section = String::new();
    let mut current: Option<(String, String, String, usize)> = None; // name, type, format, line
    let mut body = String::new();
    let mut points: Option<Array> = None;
    let mut cell_arrays: Vec<Array> = Vec::new();
    let mut element_id: Option<Array> = None;
    let (mut displacement, mut von_mises): (Option<Array>, Option<Array>) = (None, None);
    loop {
        let pos = reader.buffer_position();
        let ev = reader.read_event().map_err(|e| IoError::parse(path, line_at(pos), format!("malformed XML: {e}")))?;
        match ev {
            Event::Start(e) | Event::Empty(e) => {
                let tag = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                let attr = |key: &str| -> Option<String> {
                    e.attributes()
                        .flatten()
                        .find(|a| a.key.as_ref() == key.as_bytes())
                        .map(|a| String::from_utf8_lossy(&a.value).into_owned())
                };
                match tag.as_str() {
                    "VTKFile" => {
                        if attr("type").as_deref() != Some("UnstructuredGrid") {
                            return Err(IoError::unsupported(path, "not a VTK UnstructuredGrid file"));
                        }
                        if attr("compressor").is_some() {
                            return Err(IoError::unsupported(
                                path,
                                "compressed VTU is not supported; save uncompressed",
                            ));
                        }
                        if attr("byte_order").as_deref() == Some("BigEndian") {
                            return Err(IoError::unsupported(path, "big-endian VTU is not supported"));
                        }
                        header64 = attr("header_type").as_deref() == Some("UInt64");
                    }
                    "Points" | "Cells" | "PointData" | "CellData" => section = tag,
                    "AppendedData" => {
                        return Err(IoError::unsupported(
                            path,
                            "appended VTU data is not supported; save ascii or binary",
                        ))
                    }
                    "DataArray" => {
                        current = Some((
                            attr("Name").unwrap_or_default(),
                            attr("type").unwrap_or_default(),
                            attr("format").unwrap_or_else(|| "ascii".into()),
                            line_at(pos),
                        ));
                        body.clear();
                    }
                    _ => {}
                }
            }
            Event::Text(t) if current.is_some() => {
                body.push_str(&t.decode().map_err(|e| IoError::parse(path, line_at(pos), e.to_string()))?);
            }
            Event::End(e) if e.name().as_ref() == b"DataArray" => {
                if let Some((name, ty, format, line)) = current.take() {
                    let values = decode_array(path, line, &ty, &format, body.trim(), header64)?;
                    let arr = Array { name, values, line };
                    match section.as_str() {
                        "Points" => points = Some(arr),
                        "Cells" => cell_arrays.push(arr),
                        "CellData" if arr.name == "element_id" => element_id = Some(arr),
                        "CellData" if arr.name == "von_mises" => von_mises = Some(arr),
                        "PointData" if arr.name == "displacement" => displacement = Some(arr),
                        _ => {}
                    }
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    let points = points.ok_or_else(|| IoError::unsupported(path, "no <Points> array"))?;
    if points.values.len() % 3 != 0 {
        return Err(IoError::parse(path, points.line, "the Points array length is not a multiple of 3"));
    }
    let nodes: Vec<[f64; 3]> = points.values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let get = |n: &str| cell_arrays.iter().find(|a| a.name == n);
    let conn = get("connectivity").ok_or_else(|| IoError::unsupported(path, "no Cells/connectivity array"))?;
    let offs = get("offsets").ok_or_else(|| IoError::unsupported(path, "no Cells/offsets array"))?;
    let types = get("types").ok_or_else(|| IoError::unsupported(path, "no Cells/types array"))?;
    let as_index = |arr: &Array, v: f64| -> Result<usize, IoError> {
        if v < 0.0 || v.fract() != 0.0 {
            return Err(IoError::parse(path, arr.line, format!("'{}' holds {v}, not an index", arr.name)));
        }
        Ok(v as usize)
    };
    let mut cells = Vec::with_capacity(types.values.len());
    let mut start = 0usize;
    let faces = get("faces");
    let faceoffs = get("faceoffsets");
    for (c, &ty) in types.values.iter().enumerate() {
        let end = as_index(
            offs,
            *offs.values.get(c).ok_or_else(|| IoError::parse(path, offs.line, "fewer offsets than cells"))?,
        )?;
        if end < start || end > conn.values.len() {
            return Err(IoError::parse(path, offs.line, format!("offset of cell {c} is out of range")));
        }
        let ids: Vec<u32> = conn.values[start..end]
            .iter()
            .map(|&v| {
                let i = as_index(conn, v)?;
                if i >= nodes.len() {
                    return Err(IoError::parse(
                        path,
                        conn.line,
                        format!("cell {c} refers to point {i}, but there are {}", nodes.len()),
                    ));
                }
                Ok(i as u32)
            })
            .collect::<Result<_, _>>()?;
        start = end;
        match ty as u8 {
            VTK_TETRA if ids.len() == 4 => cells.push(Cell::Tet([ids[0], ids[1], ids[2], ids[3]])),
            VTK_HEXAHEDRON if ids.len() == 8 => cells.push(Cell::Hex(std::array::from_fn(|i| ids[i]))),
            VTK_POLYHEDRON => {
                let (Some(faces), Some(fo)) = (faces, faceoffs) else {
                    return Err(IoError::unsupported(path, "polyhedron cells need 'faces' and 'faceoffsets' arrays"));
                };
                let Some(&end) = fo.values.get(c) else {
                    return Err(IoError::parse(path, fo.line, format!("faceoffsets has no entry for cell {c}")));
                };
                let end = as_index(fo, end)?;
                let prev =
                    fo.values[..c].iter().rev().copied().find(|&v| v >= 0.0).map_or(Ok(0), |v| as_index(fo, v))?;
                if end > faces.values.len() || prev > end {
                    return Err(IoError::parse(path, fo.line, format!("faceoffsets of cell {c} out of range")));
                }
                let stream = &faces.values[prev..end];
                let mut loops = Vec::new();
                let nf = stream.first().map_or(Ok(0), |&v| as_index(faces, v))?;
                let mut k = 1;
                for _ in 0..nf {
                    let n = stream.get(k).map_or(Ok(0), |&v| as_index(faces, v))?;
                    let Some(lp) = stream.get(k + 1..k + 1 + n) else {
                        return Err(IoError::parse(path, faces.line, format!("face stream of cell {c} is truncated")));
                    };
                    let lp: Vec<u32> =
                        lp.iter().map(|&v| as_index(faces, v).map(|i| i as u32)).collect::<Result<_, _>>()?;
                    if let Some(&bad) = lp.iter().find(|&&i| i as usize >= nodes.len()) {
                        return Err(IoError::parse(
                            path,
                            faces.line,
                            format!("cell {c} refers to point {bad}, out of range"),
                        ));
                    }
                    loops.push(lp);
                    k += 1 + n;
                }
                cells.push(Cell::Polyhedron(loops));
            }
            other => {
                return Err(IoError::unsupported(
                    path,
                    format!(
                    "cell {c} has VTK type {other} with {} points (tetra 10, hexahedron 12, polyhedron 42 are read)",
                    ids.len()
                ),
                ))
            }
        }
    }
    let mut von_mises = von_mises.map(|a| a.values).filter(|v| v.len() == cells.len());
    // the engine's element order, where the file carries it
    if let Some(ids) = element_id.filter(|ids| ids.values.len() == cells.len()) {
        let mut slot: Vec<Option<(Cell, f64)>> = vec![None; cells.len()];
        for (c, (cell, &id)) in cells.into_iter().zip(&ids.values).enumerate() {
            let i = as_index(&ids, id)?;
            let stress = von_mises.as_ref().map_or(0.0, |v| v[c]);
            match slot.get_mut(i) {
                Some(s @ None) => *s = Some((cell, stress)),
                _ => return Err(IoError::parse(path, ids.line, format!("element_id {i} is out of range or repeated"))),
            }
        }
        let (ordered, stress): (Vec<Cell>, Vec<f64>) = slot.into_iter().flatten().unzip();
        cells = ordered;
        von_mises = von_mises.map(|_| stress);
    }
    let displacement = match displacement {
        Some(a) if a.values.len() == 3 * nodes.len() => {
            Some(a.values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        }
        Some(a) => return Err(IoError::parse(path, a.line, "displacement does not hold 3 values per point")),
        None => None,
    };
    let mesh = PolyMesh::from_cells(nodes, &cells).map_err(|e| IoError::mesh(path, e))?;
    Ok(VtuFrame { mesh, displacement, von_mises })
}

fn decode_array(
    path: &Path,
    line: usize,
    ty: &str,
    format: &str,
    body: &str,
    header64: bool,
) -> Result<Vec<f64>, IoError> {
    match format {
        "ascii" => body
            .split_whitespace()
            .map(|t| {
                t.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| IoError::parse(path, line, format!("'{t}' is not a finite number")))
            })
            .collect(),
        "binary" => {
            let raw = base64::engine::general_purpose::STANDARD
                .decode(body.as_bytes())
                .map_err(|e| IoError::parse(path, line, format!("bad base64 data: {e}")))?;
            let hlen = if header64 { 8 } else { 4 };
            if raw.len() < hlen {
                return Err(IoError::parse(path, line, "binary array shorter than its header"));
            }
            let n = if header64 {
                u64::from_le_bytes(raw[..8].try_into().unwrap()) as usize
            } else {
                u32::from_le_bytes(raw[..4].try_into().unwrap()) as usize
            };
            let data =
                raw.get(hlen..hlen + n).ok_or_else(|| IoError::parse(path, line, "binary array is truncated"))?;
            let size = match ty {
                "Float64" | "Int64" | "UInt64" => 8,
                "Float32" | "Int32" | "UInt32" => 4,
                "Int16" | "UInt16" => 2,
                "Int8" | "UInt8" => 1,
                _ => {
                    return Err(IoError::unsupported(
                        path,
                        format!("line {line}: DataArray type '{ty}' is not supported"),
                    ))
                }
            };
            let vals: Vec<f64> = data
                .chunks_exact(size)
                .map(|c| match ty {
                    "Float64" => f64::from_le_bytes(c.try_into().unwrap()),
                    "Int64" => i64::from_le_bytes(c.try_into().unwrap()) as f64,
                    "UInt64" => u64::from_le_bytes(c.try_into().unwrap()) as f64,
                    "Float32" => f32::from_le_bytes(c.try_into().unwrap()) as f64,
                    "Int32" => i32::from_le_bytes(c.try_into().unwrap()) as f64,
                    "UInt32" => u32::from_le_bytes(c.try_into().unwrap()) as f64,
                    "Int16" => i16::from_le_bytes(c.try_into().unwrap()) as f64,
                    "UInt16" => u16::from_le_bytes(c.try_into().unwrap()) as f64,
                    "Int8" => c[0] as i8 as f64,
                    _ => c[0] as f64,
                })
                .collect();
            if let Some(bad) = vals.iter().position(|v| !v.is_finite()) {
                return Err(IoError::parse(path, line, format!("value {bad} of the array is not finite")));
            }
            Ok(vals)
        }
        other => Err(IoError::unsupported(path, format!("line {line}: DataArray format '{other}' is not supported"))),
    }
}
