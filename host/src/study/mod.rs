//! Campaigns of whole simulated sessions.
pub mod trade;
