//! Every format at the edge: capture layouts, image readers and writers with their size limits,
//! ground truth, output folders, figures and maps, surfaces and meshes, the viewer's page.

pub mod calibration_figure;
pub mod camera;
pub mod capture_state;
pub mod export;
pub mod figure;
pub mod groundtruth;
pub mod imageio;
pub mod jpeg;
pub mod layouts;
pub mod light_files;
pub mod limits;
pub mod maps;
pub mod matfile;
pub mod photometry;
pub mod raw;
pub mod rti;
pub mod shadow_figure;
pub mod surface;
pub mod synth;
pub mod viewer;
