//! Campaigns of whole simulated sessions.
pub mod reliability;
pub mod trade;
