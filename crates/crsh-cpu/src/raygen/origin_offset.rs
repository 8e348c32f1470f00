//! Stand-in for the hemisphere sets while they are built on another branch (replaced at merge).
#![allow(missing_docs, dead_code)]
use crsh_core::Ray;
use crsh_scene::Scene;
#[derive(Clone, Copy, Debug)]
pub enum HemisphereKind {
    Center,
}
impl HemisphereKind {
    pub fn from_name(_n: &str) -> Option<Self> {
        None
    }
}
#[derive(Debug)]
pub struct Hemispheres;
impl Hemispheres {
    pub fn build(_s: &Scene, _k: HemisphereKind) -> Self {
        Hemispheres
    }
    pub fn offset_t_min(&self, _tri: u32, r: &Ray) -> f32 {
        r.t_min
    }
    pub fn cut_t_max(&self, _tri: u32, r: &Ray) -> f32 {
        r.t_max
    }
}
