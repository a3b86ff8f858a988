//! The CPU backend: the CPU runtime ([`crate::exec`]) behind the
//! [`Backend`] trait.

use crate::backend::Backend;
use crate::error::Result;
use crate::exec::CpuBackend;
use crate::job::clip::{ClipJob, ClipOutput};
use crate::job::knn::{KnnJob, Neighbors};
use crate::job::BackendKind;
use cvd_kernels::clip::NoPieces;
use std::sync::Mutex;

impl Backend for CpuBackend {
    fn kind(&self) -> BackendKind {
        BackendKind::Cpu
    }

    fn device(&self) -> String {
        format!("{} threads", self.threads())
    }

    fn knn(&self, job: &KnnJob) -> Result<Neighbors> {
        self.neighbors(job)
    }

    fn clip(&self, job: &ClipJob) -> Result<ClipOutput> {
        self.clip_into(job, &Mutex::new(Vec::<NoPieces>::new()))
    }
}
