//! Dataset readers: each turns a dataset into one [`crate::Dataset`] event stream.
