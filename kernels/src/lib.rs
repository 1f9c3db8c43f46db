//! blockflow-kernels: the per-block numerics of blockflow, as pure functions over block data.
//!
//! D3Q19 lattice ([`d3q19`]), zero-centred structure-of-arrays storage ([`field`]), TRT collision with
//! Guo forcing (eqs. 2, 3, 5 of Rettinger & Rüde 2019, [`trt`]), pull streaming and the fused kernel
//! (eq. 4, [`sweep`]), bounce-back walls ([`bounce_back`]), the fluid–particle coupling per link
//! ([`coupling`], in vector lanes [`link_batch`]) and the rigid-body hard-contact solver ([`rigid`]).
//! Nothing here knows about threads.

pub mod bounce_back;
pub mod coupling;
pub mod d3q19;
pub mod field;
pub mod link_batch;
pub mod prefetch;
pub mod real;
pub mod rigid;
pub mod simd;
pub mod sweep;
pub mod trt;

pub use field::{Layout, Pattern, PdfField, Slots};
pub use real::Real;
pub use sweep::{Segment, SweepStats};
pub use trt::TrtParams;
