// Row-major float32 products of the shapes a network's batched Jacobian takes (a few hundred rows, a width of about
// a hundred): C (R, N) = A (R, K) B (K, N), each row of the result optionally scaled column by column by
// `scale` (row i by scale's row i / group): the reverse-mode adjoint times a layer's transposed weights, then the
// layer's activation slopes of the input row it belongs to. With AVX2 and FMA: register blocks of 6 rows by 16, 8
// or 4 columns, no packing of the operands (Eigen's general product packs both per call, a large share of its
// time at these sizes), the rows left over each by Eigen's matrix-vector product; without them (the controller
// program's generic build), Eigen's product.
#pragma once
#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif
#include <type_traits>

#include <Eigen/Core>

namespace stdm {

namespace detail {
#if defined(__AVX2__) && defined(__FMA__)
// rows x width of C at (i, j): width 16 or 8 in 256-bit vectors, 4 in a 128-bit one
template <int width, int rows>
inline void gemm_block(const float* A, long lda, const float* B, long ldb, float* C, long ldc, int K, int i, int j,
                       const float* scale, long lds, int group) {
  if constexpr (width >= 8) {
    constexpr int vectors = width / 8;
    __m256 c[rows][vectors];
    for (int r = 0; r < rows; ++r)
      for (int v = 0; v < vectors; ++v) c[r][v] = _mm256_setzero_ps();
    for (int k = 0; k < K; ++k) {
      __m256 b[vectors];
      for (int v = 0; v < vectors; ++v) b[v] = _mm256_loadu_ps(B + k * ldb + j + 8 * v);
      for (int r = 0; r < rows; ++r) {
        const __m256 a = _mm256_broadcast_ss(A + (i + r) * lda + k);
        for (int v = 0; v < vectors; ++v) c[r][v] = _mm256_fmadd_ps(a, b[v], c[r][v]);
      }
    }
    for (int r = 0; r < rows; ++r)
      for (int v = 0; v < vectors; ++v) {
        __m256 value = c[r][v];
        if (scale) value = _mm256_mul_ps(value, _mm256_loadu_ps(scale + ((i + r) / group) * lds + j + 8 * v));
        _mm256_storeu_ps(C + (i + r) * ldc + j + 8 * v, value);
      }
  } else {
    __m128 c[rows];
    for (int r = 0; r < rows; ++r) c[r] = _mm_setzero_ps();
    for (int k = 0; k < K; ++k) {
      const __m128 b = _mm_loadu_ps(B + k * ldb + j);
      for (int r = 0; r < rows; ++r) c[r] = _mm_fmadd_ps(_mm_broadcast_ss(A + (i + r) * lda + k), b, c[r]);
    }
    for (int r = 0; r < rows; ++r) {
      __m128 value = c[r];
      if (scale) value = _mm_mul_ps(value, _mm_loadu_ps(scale + ((i + r) / group) * lds + j));
      _mm_storeu_ps(C + (i + r) * ldc + j, value);
    }
  }
}
#endif
}  // namespace detail

// C = A B (C not aliasing A or B); lda, ldb, ldc: the row strides; scale (R / group rows, N, stride lds) or null
inline void small_gemm(const float* A, long lda, const float* B, long ldb, float* C, long ldc, int R, int K, int N,
                       const float* scale = nullptr, long lds = 0, int group = 1) {
  using Matrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  using Stride = Eigen::OuterStride<>;
  const Eigen::Map<const Matrix, 0, Stride> right(B, K, N, Stride(ldb));
#if defined(__AVX2__) && defined(__FMA__)
  const int blocked = R - R % 6;   // rows in blocks of 6
  int j = 0;
  auto columns = [&](auto width) {
    for (; j + decltype(width)::value <= N; j += decltype(width)::value)
      for (int i = 0; i < blocked; i += 6)
        detail::gemm_block<decltype(width)::value, 6>(A, lda, B, ldb, C, ldc, K, i, j, scale, lds, group);
  };
  columns(std::integral_constant<int, 16>{});
  columns(std::integral_constant<int, 8>{});
  columns(std::integral_constant<int, 4>{});
  for (int i = 0; i < blocked; ++i)   // (the columns left of fewer than 4, one by one)
    for (int col = j; col < N; ++col) {
      float sum = 0.0f;
      for (int k = 0; k < K; ++k) sum += A[i * lda + k] * B[k * ldb + col];
      C[i * ldc + col] = scale ? sum * scale[(i / group) * lds + col] : sum;
    }
  // the rows left (fewer than 6) one by one, each Eigen's matrix-vector product (which keeps several sums apart: one
  // row in a register block would wait on its two sums' latency at every k; a general product of a few rows packs)
  for (int i = blocked; i < R; ++i) {
    Eigen::Map<Eigen::RowVectorXf> out(C + i * ldc, N);
    out.noalias() = Eigen::Map<const Eigen::RowVectorXf>(A + i * lda, K) * right;
    if (scale) out.array() *= Eigen::Map<const Eigen::RowVectorXf>(scale + (i / group) * lds, N).array();
  }
#else   // (a build without AVX2, as the controller program's generic one: Eigen's product of all rows)
  Eigen::Map<Matrix, 0, Stride> all(C, R, N, Stride(ldc));
  all.noalias() = Eigen::Map<const Matrix, 0, Stride>(A, R, K, Stride(lda)) * right;
  if (scale)
    for (int i = 0; i < R; ++i)
      all.row(i).array() *= Eigen::Map<const Eigen::RowVectorXf>(scale + (i / group) * lds, N).array();
#endif
}

}  // namespace stdm
