//! Isotropic remeshing (placeholder for the remeshing module).
