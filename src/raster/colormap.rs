//! Colour scales for the diagnostic layers (samples, distance, classes).
//! Owned by the vision/metric work (issue #3): the distance scale and its legend.
