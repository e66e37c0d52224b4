//! `cargo fuzz run rb2d`: see fuzz/README.md.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    slam_fuzz::Target::Rb2d.run(data);
});
