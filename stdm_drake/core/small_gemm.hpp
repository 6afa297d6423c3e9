// Row-major float32 products of the shapes a network's batched Jacobian takes (a few hundred rows, a width of about
// a hundred): C (R, N) = A (R, K) B (K, N), each row of the result optionally scaled column by column by
// `scale` (row i by scale's row i / group): the reverse-mode adjoint times a layer's transposed weights, then the
// layer's activation slopes of the input row it belongs to. With AVX2 and FMA: register blocks of 6 rows by 16, 8
// or 4 columns, no packing of the operands (Eigen's general product packs both per call, a large share of its
// time at these sizes), the rows left over (a rollout's single row) each in one pass over its columns; without
// them (the controller program's generic build), Eigen's product.
#pragma once
#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif
#include <algorithm>
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

// One row, c (N) = a (K) B (K, N) (times scale (N) where given), columns j.. j + 8 V (the last vector's `tail`
// columns, 1-8, through a mask): V vectors of sums, each split over U sums of every U-th k, so that a few
// columns do not wait on one sum's latency at every k (U V <= 13 registers, besides a and the load).
template <int V, int U>
inline void row_block(const float* a, int K, const float* B, long ldb, float* c, const float* scale, int j,
                      int tail) {
  const __m256i lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
  const __m256i mask = _mm256_cmpgt_epi32(_mm256_set1_epi32(tail), lanes);
  const float* last = B + j + 8 * (V - 1);
  __m256 sum[U][V];
  for (int u = 0; u < U; ++u)
    for (int v = 0; v < V; ++v) sum[u][v] = _mm256_setzero_ps();
  int k = 0;
  for (; k + U <= K; k += U)
    for (int u = 0; u < U; ++u) {
      const __m256 x = _mm256_broadcast_ss(a + k + u);
      const float* row = B + (k + u) * ldb + j;
      for (int v = 0; v < V - 1; ++v) sum[u][v] = _mm256_fmadd_ps(x, _mm256_loadu_ps(row + 8 * v), sum[u][v]);
      sum[u][V - 1] = _mm256_fmadd_ps(x, _mm256_maskload_ps(last + (k + u) * ldb, mask), sum[u][V - 1]);
    }
  for (; k < K; ++k) {
    const __m256 x = _mm256_broadcast_ss(a + k);
    const float* row = B + k * ldb + j;
    for (int v = 0; v < V - 1; ++v) sum[0][v] = _mm256_fmadd_ps(x, _mm256_loadu_ps(row + 8 * v), sum[0][v]);
    sum[0][V - 1] = _mm256_fmadd_ps(x, _mm256_maskload_ps(last + k * ldb, mask), sum[0][V - 1]);
  }
  for (int v = 0; v < V; ++v) {
    __m256 value = sum[0][v];
    for (int u = 1; u < U; ++u) value = _mm256_add_ps(value, sum[u][v]);
    if (v < V - 1) {
      if (scale) value = _mm256_mul_ps(value, _mm256_loadu_ps(scale + j + 8 * v));
      _mm256_storeu_ps(c + j + 8 * v, value);
    } else {
      if (scale) value = _mm256_mul_ps(value, _mm256_maskload_ps(scale + j + 8 * v, mask));
      _mm256_maskstore_ps(c + j + 8 * v, mask, value);
    }
  }
}

// c (N) = a (K) B (K, N) (times scale (N)): the columns in passes of at most 13 vectors of 8
inline void row_product(const float* a, int K, const float* B, long ldb, float* c, int N, const float* scale) {
  for (int j = 0; j < N;) {
    const int vectors = std::min(13, (N - j + 7) / 8);
    const int tail = std::min(8, N - j - 8 * (vectors - 1));
    switch (vectors) {
      case 1: row_block<1, 4>(a, K, B, ldb, c, scale, j, tail); break;
      case 2: row_block<2, 4>(a, K, B, ldb, c, scale, j, tail); break;
      case 3: row_block<3, 4>(a, K, B, ldb, c, scale, j, tail); break;
      case 4: row_block<4, 2>(a, K, B, ldb, c, scale, j, tail); break;
      case 5: row_block<5, 2>(a, K, B, ldb, c, scale, j, tail); break;
      case 6: row_block<6, 2>(a, K, B, ldb, c, scale, j, tail); break;
      case 7: row_block<7, 1>(a, K, B, ldb, c, scale, j, tail); break;
      case 8: row_block<8, 1>(a, K, B, ldb, c, scale, j, tail); break;
      case 9: row_block<9, 1>(a, K, B, ldb, c, scale, j, tail); break;
      case 10: row_block<10, 1>(a, K, B, ldb, c, scale, j, tail); break;
      case 11: row_block<11, 1>(a, K, B, ldb, c, scale, j, tail); break;
      case 12: row_block<12, 1>(a, K, B, ldb, c, scale, j, tail); break;
      default: row_block<13, 1>(a, K, B, ldb, c, scale, j, tail); break;
    }
    j += 8 * vectors;
  }
}
#endif
}  // namespace detail

// C = A B (C not aliasing A or B); lda, ldb, ldc: the row strides; scale (R / group rows, N, stride lds) or null
inline void small_gemm(const float* A, long lda, const float* B, long ldb, float* C, long ldc, int R, int K, int N,
                       const float* scale = nullptr, long lds = 0, int group = 1) {
  using Matrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  using Stride = Eigen::OuterStride<>;
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
  // the rows left (fewer than 6) one by one: `detail::row_product`, all of a row's columns in one pass of up to 13
  // vectors, a few columns' sums split over k (one row in the 6-row blocks would wait on its sums' latency at every
  // k; Eigen's matrix-vector product took about 1.6x as long at batch one)
  for (int i = blocked; i < R; ++i)
    detail::row_product(A + i * lda, K, B, ldb, C + i * ldc, N, scale ? scale + (i / group) * lds : nullptr);
#else   // (a build without AVX2, as the controller program's generic one: Eigen's product of all rows)
  Eigen::Map<Matrix, 0, Stride> all(C, R, N, Stride(ldc));
  all.noalias() = Eigen::Map<const Matrix, 0, Stride>(A, R, K, Stride(lda)) * Eigen::Map<const Matrix, 0, Stride>(B, K, N, Stride(ldb));
  if (scale)
    for (int i = 0; i < R; ++i)
      all.row(i).array() *= Eigen::Map<const Eigen::RowVectorXf>(scale + (i / group) * lds, N).array();
#endif
}

}  // namespace stdm
