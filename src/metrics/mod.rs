//! What a run's measurements mean for a distributed run: per-process loads and the load imbalance of
//! eq. (18) ([`load`]), the edge cut of eq. (17) ([`edge_cut`]), the modeled time of a recorded graph run
//! on `P × T` dedicated cores with messages priced at α + bytes/β ([`cost_model`]), and the per-interval
//! record of an assignment that the live run and every counterfactual of the study keep with the same
//! code ([`interval`]).

pub mod cost_model;
pub mod edge_cut;
pub mod interval;
pub mod load;
