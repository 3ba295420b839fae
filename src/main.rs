//! The `filmscope` command line (placeholder, rewritten below).
fn main() {}
