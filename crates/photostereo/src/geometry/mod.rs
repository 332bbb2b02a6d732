//! Shape from normals: integration into depth and the shadows a height field casts. Uses
//! [`crate::model`] and [`crate::base`].

pub mod contour;
pub mod integrate;
pub mod shadows;
