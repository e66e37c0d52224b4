//! `cargo fuzz run victoria_park`: see fuzz/README.md.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    slam_fuzz::Target::VictoriaPark.run(data);
});
