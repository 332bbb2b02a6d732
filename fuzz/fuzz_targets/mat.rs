//! MATLAB level-5 MAT-files (DiLiGenT's Normal_gt.mat), plain and zlib-compressed.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = photostereo::io::matfile::parse_mat(data, None);
    let _ = photostereo::io::matfile::parse_mat(data, Some("Normal_gt"));
});
