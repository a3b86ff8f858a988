//! Jobs: what crosses from the host to a backend and back — k-NN jobs and
//! their neighbour lists ([`knn`]), the sites as the kernels take them
//! ([`sites`]) and, with power weights, each site's bound of its
//! neighbours' weights (`weight_bounds`). Plain data and its validation:
//! no backend, no pass, no diagram.

pub mod knn;
pub mod sites;
pub(crate) mod weight_bounds;
