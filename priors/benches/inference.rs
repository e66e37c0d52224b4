//! One inference of the rectangular prior on a simulated square room.
fn main() {}
