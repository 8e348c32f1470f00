//! crsh-cpu (in progress)
