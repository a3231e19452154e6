//! The studies: many runs asked as one question and answered as one result. [`paper`] runs the
//! paper's scenarios and laws and writes its tables and figures beside the paper's; [`sweep`]
//! runs a grid of configs (delays, gains, seeds, links; sharded over hosts and merged), with
//! confidence intervals over seeded repeats; [`whatif`] answers what a measured latency
//! distribution would cost the tracking, from replicas run in-process. Each point is a run of the runner; the numbers are
//! the study crate's metrics; the files are the report's.

pub mod paper;
pub mod sweep;
pub mod whatif;
