//! Output: `summary.json`, the CSV time series and VTK files for ParaView.

pub mod plots;
pub mod plots_balance;
pub mod plots_sweep;
pub mod series;
pub mod summary;
pub mod vtk;
