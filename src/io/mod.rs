//! Output: `summary.json`, the CSV time series and interval table, VTK files for ParaView and the PNG
//! figures, and the animated GIF of a run's snapshots.

pub mod animation;
pub mod intervals;
pub mod plots;
pub mod series;
pub mod summary;
pub mod vtk;
