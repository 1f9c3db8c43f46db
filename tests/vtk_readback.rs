//! The VTK output read back by a parser blockflow did not write (the `vtkio` crate), checked against
//! the run's own record of the same step: the block pieces cover the domain (`summary.json`: blocks,
//! cells), the fluid and sphere-covered cells are the fluid cells, the density summed over the fluid
//! cells is the mass of `series.csv`, and the spheres are the bodies with their speeds and heights
//! (`summary.json`'s observables). The blocks are written with `run.vtk_encoding = "base64"`, the
//! well-formed XML that such parsers read (raw appended bytes are not XML; the unit tests of `io::vtk`
//! show the base64 files hold the raw files' bytes).

use std::path::Path;
use std::process::Command;
use vtkio::model::{Attribute, DataSet, Piece};
use vtkio::Vtk;

/// The cell-data arrays of one `.vti` block: (cells, density, velocity, flags).
fn read_block(path: &Path) -> (usize, Vec<f64>, Vec<f64>, Vec<u8>) {
    let vtk = Vtk::import(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let DataSet::ImageData { mut pieces, .. } = vtk.data else {
        panic!("{} is not ImageData", path.display())
    };
    assert_eq!(pieces.len(), 1, "one piece per block file");
    let piece = pieces.remove(0).into_loaded_piece_data(None).unwrap();
    let cells = piece.extent.num_cells() as usize;
    let (mut rho, mut vel, mut flags) = (None, None, None);
    for a in piece.data.cell {
        let Attribute::DataArray(d) = a else { continue };
        match d.name.as_str() {
            "density" => rho = d.data.cast_into::<f64>(),
            "velocity" => vel = d.data.cast_into::<f64>(),
            "flags" => flags = d.data.into_vec::<u8>(),
            _ => {}
        }
    }
    (cells, rho.unwrap(), vel.unwrap(), flags.unwrap())
}

/// A named point-data array of a `.vtp` file and the point count.
fn read_points(path: &Path, name: &str) -> (usize, Vec<f64>, Vec<f64>) {
    let vtk = Vtk::import(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let DataSet::PolyData { mut pieces, .. } = vtk.data else {
        panic!("{} is not PolyData", path.display())
    };
    let piece = match pieces.remove(0) {
        Piece::Inline(p) => *p,
        other => other.into_loaded_piece_data(None).unwrap(),
    };
    let points: Vec<f64> = piece.points.cast_into().unwrap();
    let array = piece
        .data
        .point
        .into_iter()
        .find_map(|a| match a {
            Attribute::DataArray(d) if d.name == name => d.data.cast_into::<f64>(),
            _ => None,
        })
        .unwrap_or_else(|| panic!("{}: no point array {name}", path.display()));
    (points.len() / 3, points, array)
}

#[test]
fn vtk_output_matches_the_summary_and_series_of_the_same_step() {
    let out = std::env::temp_dir().join(format!("blockflow-vtk-readback-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    // The demo (hopper, 60 spheres, 2 processes) for 100 steps with VTK at steps 0 and 100.
    let o = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(["run", "--steps", "100", "--vtk", "100", "--set", "run.png_every=1000"])
        .args(["--set", "run.vtk_encoding=\"base64\"", "--out"])
        .arg(&out)
        .output()
        .expect("binary runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();

    let step = out.join("vtk/step_00000100");
    let mut files: Vec<_> = std::fs::read_dir(&step).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    assert_eq!(files.len() as u64, s["blocks"].as_u64().unwrap(), "one piece per block");
    let (mut cells, mut fluid, mut mass) = (0usize, 0usize, 0.0f64);
    for f in &files {
        let (n, rho, vel, flags) = read_block(f);
        assert_eq!((rho.len(), vel.len(), flags.len()), (n, 3 * n, n), "{}", f.display());
        cells += n;
        for (k, &fl) in flags.iter().enumerate() {
            // Fluid cells carry bit 1; cells under a sphere are written as 32 and are fluid cells too.
            if fl & 1 != 0 || fl == 32 {
                fluid += 1;
            }
            if fl & 1 != 0 {
                mass += rho[k];
            }
        }
    }
    assert_eq!(cells as u64, s["cells"].as_u64().unwrap());
    assert_eq!(fluid as u64, s["fluid_cells"].as_u64().unwrap());
    // series.csv's mass at step 100 is Σρ over the fluid cells; the VTK densities are Float32, so the
    // sum agrees to f32 rounding (2^-24 relative per value, well under 1e-6 for the sum).
    let series = std::fs::read_to_string(out.join("series.csv")).unwrap();
    let row = series
        .lines()
        .find(|l| l.starts_with("100,"))
        .expect("a row at step 100");
    let series_mass: f64 = row.split(',').nth(2).unwrap().parse().unwrap();
    assert!(
        ((mass - series_mass) / series_mass).abs() < 1e-6,
        "VTK mass {mass} against series.csv {series_mass}"
    );

    let vtp = out.join("vtk/particles_00000100.vtp");
    let (n, points, velocity) = read_points(&vtp, "velocity");
    assert_eq!(n as f64, s["observables"]["bodies"].as_f64().unwrap());
    // Written with all digits ({:?}), so the speeds come back bit for bit.
    let vmax = velocity
        .chunks(3)
        .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
        .fold(0.0, f64::max);
    let max_speed = s["observables"]["max_speed"].as_f64().unwrap();
    assert!(
        (vmax - max_speed).abs() <= 1e-15 * max_speed,
        "{vmax} against {max_speed}"
    );
    let lz = (s["block_grid"][2].as_u64().unwrap() * s["block_size"][2].as_u64().unwrap()) as f64;
    let mean_z = points.chunks(3).map(|p| p[2]).sum::<f64>() / n as f64;
    let mean_height = s["observables"]["mean_height"].as_f64().unwrap();
    assert!(
        (mean_z / lz - mean_height).abs() < 1e-12,
        "{} against {mean_height}",
        mean_z / lz
    );
    let (_, _, radius) = read_points(&vtp, "radius");
    assert!(
        radius.iter().all(|&r| (r - 3.75).abs() < 1e-12),
        "D = 7.5 cells: {radius:?}"
    );
    std::fs::remove_dir_all(&out).ok();
}
