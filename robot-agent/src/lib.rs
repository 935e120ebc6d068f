//! robot-agent library
