//! Points projected into the cameras of a frame, searched for camera by camera: the one
//! loop of the motion-model and local-map searches over a rig.

use ferroslam_features::{MatchOptions, ProjectionQuery};

use crate::frame::Frame;

/// Points projected into one camera of a frame, searched for together.
#[derive(Debug)]
pub(super) struct ProjectionSearch<S> {
    queries: Vec<ProjectionQuery>,
    u_right: Vec<f64>,
    sources: Vec<S>,
}

impl<S> Default for ProjectionSearch<S> {
    fn default() -> Self {
        Self {
            queries: Vec::new(),
            u_right: Vec::new(),
            sources: Vec::new(),
        }
    }
}

impl<S: Copy> ProjectionSearch<S> {
    /// Forgets the queries, keeping the buffers for the next frame.
    pub(super) fn clear(&mut self) {
        self.queries.clear();
        self.u_right.clear();
        self.sources.clear();
    }

    /// Adds a query with the right coordinate it predicts and what it stands for.
    pub(super) fn push(&mut self, query: ProjectionQuery, u_right: f64, source: S) {
        self.queries.push(query);
        self.u_right.push(u_right);
        self.sources.push(source);
    }

    /// The keypoints of camera `camera` of `frame` found, with what each query stood for.
    pub(super) fn run(
        &self,
        frame: &Frame,
        camera: usize,
        taken: &[bool],
        opts: &MatchOptions,
    ) -> Vec<(usize, S)> {
        if self.queries.is_empty() {
            return Vec::new();
        }
        let found = frame.search_by_projection(camera, &self.queries, &self.u_right, taken, opts);
        found
            .iter()
            .zip(&self.sources)
            .filter_map(|(hit, &source)| hit.map(|(i, _)| (i, source)))
            .collect()
    }
}
