//! The data the engine works on, in memory and free of files: images, lights and the light model
//! (distant or near, per pixel), the capture with its sample store, and the memory plan. Uses only
//! [`crate::base`].

pub mod capture;
pub mod image;
pub mod lightmodel;
pub mod lights;
pub mod memory;
pub mod store;
