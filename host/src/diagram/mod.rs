//! The clipped Voronoi diagram: the job and its results
//! ([`voronoi`]), the second pass that finishes what the kernels could
//! not ([`second_pass`]), each site's faces and neighbours ([`faces`]),
//! the pieces of each cell inside each tet ([`pieces`]) and each cell as
//! one polyhedron ([`polyhedra`]); with power weights, each site's local
//! bound of its neighbours' weights (`weight_bounds`); the cells of a
//! periodic box, through the sites' images ([`periodic`]); the sites as
//! the kernels take them, duplicates merged, and where each input site
//! went ([`sites`]).

pub mod faces;
pub mod periodic;
pub mod pieces;
pub mod polyhedra;
pub mod second_pass;
pub mod sites;
pub mod voronoi;
pub(crate) mod weight_bounds;
