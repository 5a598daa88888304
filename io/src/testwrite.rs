//! Writers for formats eprop reads but does not write, for round-trip tests and fuzz seeds.
