//! Camera calibrations from other tools: OpenCV `cv::FileStorage` files and COLMAP text models.
