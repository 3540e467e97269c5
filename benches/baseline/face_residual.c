/* The face likelihood's residual epsilon (eq. 10-13 of the face paper) as the plain
 * single-threaded C loop a programmer would write: the yardstick the Rust reference
 * (face_tracker::likelihood::residual_error) must be at least as fast as. Same arithmetic:
 * R = Rx Ry Rz, a point is visible when (R N)_z >= 0, p = S R2x3 P + (Tx, Ty), bilinear
 * sampling of 8-bit levels inside [0, w-1] x [0, h-1] (outside: rho = 1) with the weights
 * rounded to 8 fractional bits as a GPU's texture unit rounds them
 * (pf_gpu::image::quantised_weight),
 * kappa = (alpha I - J) / J, rho = kappa^2 / (kappa^2 + 1) as d^2 / (d^2 + J^2) with
 * d = alpha I - J (one division), summed in double; epsilon = 1 when
 * fewer than min_visible_share of the points are visible.
 *
 * points: 8 floats per point, (Px, Py, Pz, J, Nx, Ny, Nz, 0), the template's memory layout. */
#include <math.h>
#include <stddef.h>
#include <stdint.h>

double streampf_face_residual_c(const float state[7], const float *points, size_t count,
                                const uint8_t *pixels, uint32_t width, uint32_t height,
                                float min_visible_share) {
    float sx = sinf(state[3]), cx = cosf(state[3]);
    float sy = sinf(state[4]), cy = cosf(state[4]);
    float sz = sinf(state[5]), cz = cosf(state[5]);
    /* Rows of Rx Ry Rz. */
    float r[3][3] = {
        {cy * cz, -cy * sz, sy},
        {sx * sy * cz + cx * sz, -sx * sy * sz + cx * cz, -sx * cy},
        {-cx * sy * cz + sx * sz, cx * sy * sz + sx * cz, cx * cy},
    };
    float s = state[2], tx = state[0], ty = state[1], alpha = state[6];
    float xmax = (float)(width - 1), ymax = (float)(height - 1);
    double sum = 0.0;
    size_t visible = 0;
    for (size_t i = 0; i < count; i++) {
        const float *q = points + 8 * i;
        if (r[2][0] * q[4] + r[2][1] * q[5] + r[2][2] * q[6] < 0.0f) continue;
        visible++;
        float x = s * (r[0][0] * q[0] + r[0][1] * q[1] + r[0][2] * q[2]) + tx;
        float y = s * (r[1][0] * q[0] + r[1][1] * q[1] + r[1][2] * q[2]) + ty;
        if (!(x >= 0.0f && y >= 0.0f && x <= xmax && y <= ymax)) {
            sum += 1.0;
            continue;
        }
        uint32_t x0 = (uint32_t)x, y0 = (uint32_t)y;
        if (x0 > width - 2) x0 = width - 2;
        if (y0 > height - 2) y0 = height - 2;
        float fx = (float)(int32_t)((x - (float)x0) * 256.0f + 0.5f) * (1.0f / 256.0f);
        float fy = (float)(int32_t)((y - (float)y0) * 256.0f + 0.5f) * (1.0f / 256.0f);
        const uint8_t *p = pixels + (size_t)y0 * width + x0;
        float top = p[0] * (1.0f - fx) + p[1] * fx;
        float bottom = p[width] * (1.0f - fx) + p[width + 1] * fx;
        float intensity = top * (1.0f - fy) + bottom * fy;
        float d = alpha * intensity - q[3];
        float d2 = d * d;
        sum += (double)(d2 / (d2 + q[3] * q[3]));
    }
    if (visible == 0 || (float)visible < min_visible_share * (float)count) return 1.0;
    return sum / (double)visible;
}
