//! bus-schema
