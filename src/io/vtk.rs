//! VTK output for ParaView: one XML ImageData file per block and step, tied together per step by a
//! multiblock file and over time by a collection file.
//!
//! Layout under the output directory `dir`:
//! - `dir/vtk/step_<step:08>/block_<id:05>.vti`: one block's interior cells (VTK XML ImageData,
//!   appended binary, little endian, as raw bytes or base64 text: [`VtkEncoding`]). Cell data `density`
//!   (Float32), `velocity` (Float32, 3 components) and `flags` (UInt8, the cell flag bits). Lattice
//!   units: Δx = 1, the global domain's first cell has its centre at (0.5, 0.5, 0.5).
//! - `dir/vtk/step_<step:08>.vtm`: multiblock dataset listing the blocks of one step.
//! - `dir/fluid.pvd`: collection of every step written so far, with the simulated time as timestep.
//!
//! In ParaView: File > Open > `fluid.pvd`, then Apply; colour by `density` or `velocity`, and use the
//! time controls to step through the series. The `flags` array lets a Threshold filter hide walls: keep
//! the cells having the fluid bit (1). Fluid cells hold 1, or 3 next to a boundary, while walls (4, 8) and
//! outside cells (16) lack that bit, so Threshold on `flags` with the range 1 to 3 shows only the fluid.

pub use crate::config::VtkEncoding;
use crate::util::fs::{tmp_beside, write_atomic_to};
use base64::Engine;
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};

/// One block's cell data for one output step. Arrays are interior cells only, x fastest, then y, then z;
/// length = `size[0] * size[1] * size[2]`.
pub struct VtkPiece<'a> {
    /// Block identifier; names the file `block_<id:05>.vti`. Must be unique within a step.
    pub block_id: usize,
    /// Global cell coordinates of the block's first interior cell.
    pub origin: [usize; 3],
    /// Interior cells per axis.
    pub size: [usize; 3],
    /// Full density rho (about 1.0), one value per cell.
    pub density: &'a [f64],
    /// Velocity in lattice units, one vector per cell.
    pub velocity: &'a [[f64; 3]],
    /// Cell flag bits (fluid=1, near-boundary=2, no-slip wall=4, moving wall=8, outside=16), one per cell.
    pub flags: &'a [u8],
}

/// A time series of VTK output in a directory: `.vti` per block, `.vtm` per step and `fluid.pvd` overall.
pub struct VtkSeries {
    dir: PathBuf,
    encoding: VtkEncoding,
    steps: Vec<(u64, f64)>,
}

impl VtkSeries {
    /// Prepares `dir/vtk/` (creating it) for block files whose arrays are stored as `encoding`. Nothing
    /// else is written until [`VtkSeries::write_step`].
    pub fn new(dir: &Path, encoding: VtkEncoding) -> io::Result<Self> {
        fs::create_dir_all(dir.join("vtk"))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            encoding,
            steps: Vec::new(),
        })
    }

    /// Writes one step: one `.vti` per piece in `dir/vtk/step_<step:08>/`, the multiblock file
    /// `dir/vtk/step_<step:08>.vtm` and the collection `dir/fluid.pvd` listing every step so far with
    /// timestep `time`. Each file is written under a temporary name and renamed into place. Writing the
    /// same step number again replaces its entry. Fails with `InvalidInput`, before writing anything,
    /// if a piece's array lengths do not match its size, block ids repeat, or `time` is not finite.
    pub fn write_step(&mut self, step: u64, time: f64, pieces: &[VtkPiece]) -> io::Result<()> {
        if !time.is_finite() {
            return Err(invalid(format!("VTK step {step}: time {time} is not finite")));
        }
        for (i, p) in pieces.iter().enumerate() {
            check_piece(p)?;
            if pieces[..i].iter().any(|q| q.block_id == p.block_id) {
                return Err(invalid(format!(
                    "VTK step {step}: block id {} appears twice",
                    p.block_id
                )));
            }
        }
        self.write_blocks(step, pieces)?;
        let ids: Vec<usize> = pieces.iter().map(|p| p.block_id).collect();
        self.write_index(step, time, &ids)
    }

    /// Writes the `.vti` files of one step's pieces into `dir/vtk/step_<step:08>/` (each under a
    /// temporary name, then renamed): the part of [`VtkSeries::write_step`] that each rank does for its
    /// own blocks.
    pub fn write_blocks(&self, step: u64, pieces: &[VtkPiece]) -> io::Result<()> {
        for p in pieces {
            check_piece(p)?;
        }
        let step_name = format!("step_{step:08}");
        let vtk_dir = self.dir.join("vtk");
        fs::create_dir_all(vtk_dir.join(&step_name))?;
        for p in pieces {
            let file = format!("{step_name}/block_{:05}.vti", p.block_id);
            write_atomic(&vtk_dir.join(&file), |w| write_vti(w, p, self.encoding))?;
        }
        Ok(())
    }

    /// Writes the multiblock file of one step, listing the blocks `block_ids` in that order, and the
    /// collection `dir/fluid.pvd` with every step so far at timestep `time` (writing a step again
    /// replaces its entry): the part of [`VtkSeries::write_step`] done once per step.
    pub fn write_index(&mut self, step: u64, time: f64, block_ids: &[usize]) -> io::Result<()> {
        if !time.is_finite() {
            return Err(invalid(format!("VTK step {step}: time {time} is not finite")));
        }
        let step_name = format!("step_{step:08}");
        let vtk_dir = self.dir.join("vtk");
        let mut vtm = String::from(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"vtkMultiBlockDataSet\" version=\"1.0\" \
             byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <vtkMultiBlockDataSet>\n",
        );
        for (i, id) in block_ids.iter().enumerate() {
            let file = format!("{step_name}/block_{id:05}.vti");
            vtm += &format!("    <DataSet index=\"{i}\" name=\"block_{id}\" file=\"{file}\"/>\n");
        }
        vtm += "  </vtkMultiBlockDataSet>\n</VTKFile>\n";
        write_atomic(&vtk_dir.join(format!("{step_name}.vtm")), |w| {
            w.write_all(vtm.as_bytes())
        })?;

        let mut steps = self.steps.clone();
        match steps.iter_mut().find(|(s, _)| *s == step) {
            Some(entry) => entry.1 = time,
            None => steps.push((step, time)),
        }
        let mut pvd = String::from(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  \
             <Collection>\n",
        );
        for (s, t) in &steps {
            pvd += &format!("    <DataSet timestep=\"{t:?}\" group=\"\" part=\"0\" file=\"vtk/step_{s:08}.vtm\"/>\n");
        }
        pvd += "  </Collection>\n</VTKFile>\n";
        write_atomic(&self.dir.join("fluid.pvd"), |w| w.write_all(pvd.as_bytes()))?;
        self.steps = steps;
        Ok(())
    }

    /// Number of steps written so far.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// True if no step has been written yet.
    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }
}

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

fn check_piece(p: &VtkPiece) -> io::Result<()> {
    let [nx, ny, nz] = p.size;
    let n = nx.checked_mul(ny).and_then(|v| v.checked_mul(nz));
    let bad = |what: &str, len: usize| {
        invalid(format!(
            "VTK block {}: {what} has {len} entries, expected {nx}*{ny}*{nz} = {}",
            p.block_id,
            n.map_or("overflow".to_string(), |n| n.to_string())
        ))
    };
    for (what, len) in [
        ("density", p.density.len()),
        ("velocity", p.velocity.len()),
        ("flags", p.flags.len()),
    ] {
        if n != Some(len) {
            return Err(bad(what, len));
        }
    }
    Ok(())
}

/// Writes `path` through `path.tmp` and a rename, only once everything was written ([`write_atomic_to`]).
fn write_atomic(path: &Path, body: impl FnOnce(&mut BufWriter<File>) -> io::Result<()>) -> io::Result<()> {
    write_atomic_to(path, &tmp_beside(path), false, body).map_err(|(_, e)| e)
}

/// One Float32 data array of the appended section: the UInt64 byte count, then the values (little endian).
fn appended_array(values: impl Iterator<Item = f64>, len: usize) -> Vec<u8> {
    let mut buf = Vec::with_capacity(8 + 4 * len);
    buf.extend_from_slice(&(4 * len as u64).to_le_bytes());
    values.for_each(|v| buf.extend_from_slice(&(v as f32).to_le_bytes()));
    buf
}

fn write_vti(w: &mut impl Write, p: &VtkPiece, encoding: VtkEncoding) -> io::Result<()> {
    let (o, s) = (p.origin, p.size);
    let extent: Vec<String> = (0..3)
        .flat_map(|a| [o[a], o[a] + s[a]])
        .map(|v| v.to_string())
        .collect();
    let extent = extent.join(" ");
    let density = appended_array(p.density.iter().copied(), p.density.len());
    let velocity = appended_array(p.velocity.iter().flatten().copied(), 3 * p.velocity.len());
    let mut flags = Vec::with_capacity(8 + p.flags.len());
    flags.extend_from_slice(&(p.flags.len() as u64).to_le_bytes());
    flags.extend_from_slice(p.flags);
    // Raw: the arrays follow each other byte for byte. Base64: each array (count and values together)
    // is encoded on its own, and the offsets count characters of the encoded text, as VTK reads it.
    let arrays: [Vec<u8>; 3] = match encoding {
        VtkEncoding::Raw => [density, velocity, flags],
        VtkEncoding::Base64 => {
            [density, velocity, flags].map(|a| base64::engine::general_purpose::STANDARD.encode(a).into_bytes())
        }
    };
    let off_velocity = arrays[0].len();
    let off_flags = off_velocity + arrays[1].len();
    let name = encoding.name();
    write!(
        w,
        "<?xml version=\"1.0\"?>\n\
         <VTKFile type=\"ImageData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  \
         <ImageData WholeExtent=\"{extent}\" Origin=\"0 0 0\" Spacing=\"1 1 1\">\n    \
         <Piece Extent=\"{extent}\">\n      \
         <CellData Scalars=\"density\" Vectors=\"velocity\">\n        \
         <DataArray type=\"Float32\" Name=\"density\" NumberOfComponents=\"1\" format=\"appended\" \
         offset=\"0\"/>\n        \
         <DataArray type=\"Float32\" Name=\"velocity\" NumberOfComponents=\"3\" format=\"appended\" \
         offset=\"{off_velocity}\"/>\n        \
         <DataArray type=\"UInt8\" Name=\"flags\" NumberOfComponents=\"1\" format=\"appended\" \
         offset=\"{off_flags}\"/>\n      \
         </CellData>\n    \
         </Piece>\n  \
         </ImageData>\n  \
         <AppendedData encoding=\"{name}\">\n   _"
    )?;
    for a in &arrays {
        w.write_all(a)?;
    }
    w.write_all(b"\n  </AppendedData>\n</VTKFile>\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .subsec_nanos();
        let dir = std::env::temp_dir().join(format!("blockflow_vtk_{name}_{}_{nanos}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    struct Data {
        density: Vec<f64>,
        velocity: Vec<[f64; 3]>,
        flags: Vec<u8>,
    }

    fn data(n: usize, shift: f64) -> Data {
        Data {
            density: (0..n).map(|i| 1.0 + shift + 0.001 * i as f64).collect(),
            velocity: (0..n).map(|i| [0.01 * i as f64, -0.02, shift]).collect(),
            flags: (0..n).map(|i| if i % 3 == 0 { 4 } else { 1 }).collect(),
        }
    }

    fn piece(id: usize, origin: [usize; 3], size: [usize; 3], d: &Data) -> VtkPiece<'_> {
        VtkPiece {
            block_id: id,
            origin,
            size,
            density: &d.density,
            velocity: &d.velocity,
            flags: &d.flags,
        }
    }

    fn u64_at(b: &[u8], at: usize) -> u64 {
        u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
    }

    /// Checks the appended offsets and byte counts; returns the first density value.
    fn check_vti(path: &Path, n: usize) -> f32 {
        let bytes = fs::read(path).unwrap();
        let marker = b"<AppendedData encoding=\"raw\">";
        let pos = bytes.windows(marker.len()).position(|w| w == marker).unwrap();
        let header = std::str::from_utf8(&bytes[..pos]).unwrap();
        let data_start = pos + bytes[pos..].iter().position(|&b| b == b'_').unwrap() + 1;
        let offsets: Vec<usize> = header
            .split("offset=\"")
            .skip(1)
            .map(|s| s[..s.find('"').unwrap()].parse().unwrap())
            .collect();
        let expected = [4 * n, 12 * n, n];
        assert_eq!(offsets.len(), 3);
        for (off, len) in offsets.iter().zip(expected) {
            assert_eq!(u64_at(&bytes, data_start + off), len as u64);
        }
        let end = data_start + offsets[2] + 8 + n;
        assert!(bytes[end..].starts_with(b"\n  </AppendedData>\n</VTKFile>\n"));
        f32::from_le_bytes(bytes[data_start + 8..data_start + 12].try_into().unwrap())
    }

    #[test]
    fn writes_series() {
        let dir = scratch("series");
        let mut series = VtkSeries::new(&dir, VtkEncoding::Raw).unwrap();
        assert!(series.is_empty() && dir.join("vtk").is_dir());
        let (a, b) = (data(4 * 3 * 2, 0.0), data(2 * 3 * 2, 0.5));
        let pieces = [piece(0, [0, 0, 0], [4, 3, 2], &a), piece(7, [4, 0, 0], [2, 3, 2], &b)];
        series.write_step(0, 0.0, &pieces).unwrap();
        series.write_step(100, 2.5, &pieces).unwrap();
        assert_eq!(series.len(), 2);

        let vti = dir.join("vtk/step_00000100/block_00007.vti");
        assert_eq!(check_vti(&dir.join("vtk/step_00000000/block_00000.vti"), 24), 1.0);
        assert_eq!(check_vti(&vti, 12), 1.5);
        let text = String::from_utf8_lossy(&fs::read(&vti).unwrap()).into_owned();
        assert!(text.contains("WholeExtent=\"4 6 0 3 0 2\"") && text.contains("<Piece Extent=\"4 6 0 3 0 2\">"));

        let vtm = fs::read_to_string(dir.join("vtk/step_00000100.vtm")).unwrap();
        assert!(vtm.contains("<DataSet index=\"0\" name=\"block_0\" file=\"step_00000100/block_00000.vti\"/>"));
        assert!(vtm.contains("<DataSet index=\"1\" name=\"block_7\" file=\"step_00000100/block_00007.vti\"/>"));
        let pvd = fs::read_to_string(dir.join("fluid.pvd")).unwrap();
        assert!(pvd.contains("timestep=\"0.0\" group=\"\" part=\"0\" file=\"vtk/step_00000000.vtm\""));
        assert!(pvd.contains("timestep=\"2.5\" group=\"\" part=\"0\" file=\"vtk/step_00000100.vtm\""));
        let leftovers = fs::read_dir(dir.join("vtk")).unwrap().flatten();
        assert!(leftovers
            .into_iter()
            .all(|e| !e.file_name().to_string_lossy().ends_with(".tmp")));
        fs::remove_dir_all(&dir).unwrap();
    }

    /// The offsets of a block file and the bytes of its appended section.
    fn appended(path: &Path) -> (Vec<usize>, Vec<u8>) {
        let bytes = fs::read(path).unwrap();
        let section = bytes.windows(13).position(|w| w == b"<AppendedData").unwrap();
        let start = section + bytes[section..].iter().position(|&b| b == b'_').unwrap() + 1;
        let end = bytes.len() - b"\n  </AppendedData>\n</VTKFile>\n".len();
        let header = std::str::from_utf8(&bytes[..start]).unwrap();
        let offsets = header
            .split("offset=\"")
            .skip(1)
            .map(|s| s[..s.find('"').unwrap()].parse().unwrap())
            .collect();
        (offsets, bytes[start..end].to_vec())
    }

    #[test]
    fn base64_files_hold_the_raw_bytes() {
        let dir = scratch("base64");
        let a = data(5 * 3 * 2, 0.25);
        let pieces = [piece(2, [0, 3, 0], [5, 3, 2], &a)];
        VtkSeries::new(&dir.join("raw"), VtkEncoding::Raw)
            .unwrap()
            .write_step(4, 1.0, &pieces)
            .unwrap();
        VtkSeries::new(&dir.join("b64"), VtkEncoding::Base64)
            .unwrap()
            .write_step(4, 1.0, &pieces)
            .unwrap();
        let file = "vtk/step_00000004/block_00002.vti";
        let (raw_offsets, raw) = appended(&dir.join("raw").join(file));
        let (offsets, text) = appended(&dir.join("b64").join(file));
        let text = std::str::from_utf8(&text).expect("base64 is text");
        // Each array decodes on its own from its character offset to the next one.
        let mut decoded = Vec::new();
        let ends = offsets.iter().skip(1).copied().chain([text.len()]);
        for (from, to) in offsets.iter().zip(ends) {
            let chunk = &text[*from..to];
            decoded.extend(base64::engine::general_purpose::STANDARD.decode(chunk).unwrap());
        }
        assert_eq!(decoded, raw);
        assert_eq!(raw_offsets, [0, 8 + 4 * 30, 8 + 4 * 30 + 8 + 12 * 30]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn rejects_length_mismatch() {
        let dir = scratch("mismatch");
        let mut series = VtkSeries::new(&dir, VtkEncoding::Raw).unwrap();
        let mut d = data(8, 0.0);
        d.velocity.pop();
        let err = series
            .write_step(1, 0.1, &[piece(3, [0, 0, 0], [2, 2, 2], &d)])
            .unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
        assert!(err.to_string().contains("velocity"), "{err}");
        assert!(series.is_empty() && !dir.join("fluid.pvd").exists());
        fs::remove_dir_all(&dir).unwrap();
    }
}

/// One rigid body as a VTK point.
#[derive(Clone, Copy, Debug)]
pub struct VtkParticle {
    /// Body id.
    pub id: u64,
    /// Centre.
    pub position: [f64; 3],
    /// Radius.
    pub radius: f64,
    /// Translational velocity.
    pub velocity: [f64; 3],
    /// Angular velocity.
    pub angular_velocity: [f64; 3],
    /// Orientation quaternion (x, y, z, w).
    pub orientation: [f64; 4],
    /// Hydrodynamic force held over the last step.
    pub force: [f64; 3],
}

/// A time series of the particles: `vtk/particles_<step>.vtp` (points with id, radius, velocity, angular
/// velocity, orientation and force; in ParaView apply *Glyph* → Sphere, scale by `radius`, factor 2)
/// and `particles.pvd`.
pub struct ParticleVtkSeries {
    dir: PathBuf,
    steps: Vec<(u64, f64)>,
}

impl ParticleVtkSeries {
    /// Prepares `dir/vtk/`.
    pub fn new(dir: &Path) -> io::Result<Self> {
        fs::create_dir_all(dir.join("vtk"))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            steps: Vec::new(),
        })
    }

    /// Writes the particles of one step and rewrites `particles.pvd`.
    pub fn write_step(&mut self, step: u64, time: f64, particles: &[VtkParticle]) -> io::Result<()> {
        let n = particles.len();
        let mut s = format!(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\">\n  \
             <PolyData>\n    <Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" \
             NumberOfStrips=\"0\" NumberOfPolys=\"0\">\n      <Points>\n        \
             <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n"
        );
        for p in particles {
            s += &format!(
                "          {:?} {:?} {:?}\n",
                p.position[0], p.position[1], p.position[2]
            );
        }
        s += "        </DataArray>\n      </Points>\n      <Verts>\n        \
              <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n";
        for i in 0..n {
            s += &format!("          {i}\n");
        }
        s += "        </DataArray>\n        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n";
        for i in 0..n {
            s += &format!("          {}\n", i + 1);
        }
        s += "        </DataArray>\n      </Verts>\n      <PointData Scalars=\"radius\" Vectors=\"velocity\">\n";
        let mut array = |name: &str, comps: usize, ty: &str, f: &dyn Fn(&VtkParticle) -> Vec<f64>| {
            s += &format!(
                "        <DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{comps}\" format=\"ascii\">\n"
            );
            for p in particles {
                let v: Vec<String> = f(p)
                    .iter()
                    .map(|x| {
                        if ty == "Int64" {
                            format!("{}", *x as i64)
                        } else {
                            format!("{x:?}")
                        }
                    })
                    .collect();
                s += &format!("          {}\n", v.join(" "));
            }
            s += "        </DataArray>\n";
        };
        array("id", 1, "Int64", &|p| vec![p.id as f64]);
        array("radius", 1, "Float64", &|p| vec![p.radius]);
        array("velocity", 3, "Float64", &|p| p.velocity.to_vec());
        array("angular_velocity", 3, "Float64", &|p| p.angular_velocity.to_vec());
        array("orientation", 4, "Float64", &|p| p.orientation.to_vec());
        array("force", 3, "Float64", &|p| p.force.to_vec());
        s += "      </PointData>\n    </Piece>\n  </PolyData>\n</VTKFile>\n";
        let file = format!("particles_{step:08}.vtp");
        write_atomic(&self.dir.join("vtk").join(&file), |w| w.write_all(s.as_bytes()))?;
        match self.steps.iter_mut().find(|(x, _)| *x == step) {
            Some(e) => e.1 = time,
            None => self.steps.push((step, time)),
        }
        let mut pvd = String::from(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  \
             <Collection>\n",
        );
        for (st, t) in &self.steps {
            pvd += &format!(
                "    <DataSet timestep=\"{t:?}\" group=\"\" part=\"0\" file=\"vtk/particles_{st:08}.vtp\"/>\n"
            );
        }
        pvd += "  </Collection>\n</VTKFile>\n";
        write_atomic(&self.dir.join("particles.pvd"), |w| w.write_all(pvd.as_bytes()))
    }
}
