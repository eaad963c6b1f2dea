//! `glimpse bench`: the speed-versus-accuracy study (issue #4).
