//! Reconstruction metrics: NRMSE, PSNR, SSIM, regions, reprojection.
