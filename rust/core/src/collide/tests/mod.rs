//! Tests of the collision module against the public CCD data sets.

#[allow(dead_code)]
mod data;
mod datasets;
mod ccd_props;
mod funnel;
mod queries;
mod response;
