//! Scene formats, images, volumes and meshes on disk.
