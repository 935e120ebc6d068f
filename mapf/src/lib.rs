//! Shared-grid multi-agent path finding (MAPF): everything the coordinator decides when it is
//! the authority of one grid shared by a fleet. Pure: no IO, no bus, no clocks.
#![deny(missing_docs)]
