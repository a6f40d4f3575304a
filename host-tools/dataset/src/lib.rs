//! The sts-twin-dataset/1 format: reading and writing measured dynamic-error datasets.
#![deny(missing_docs)]
