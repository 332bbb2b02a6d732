//! List files (count line, image paths, mask path). Paths resolve against the current folder.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = photostereo::io::limits::text_from_bytes(data) {
        let _ = photostereo::io::layouts::parse_list_file(&text, std::path::Path::new("list.txt"));
    }
});
