//! Photodiode sampling: ADC1 on PA1 (IN1), converting continuously at a fixed rate, DMA
//! into a raw circular buffer, decimated by 256 in a 1 kHz TIM5 interrupt into a bounded
//! ring of 16-bit-effective samples that `drain_samples` empties.
//!
//! Rates: ADCCLK = PCLK2 96 MHz / 4 = 24 MHz (embassy's `Adc::new` prescaler); 84-cycle
//! sampling + 12-cycle conversion = 96 ADC clocks, so 250,000 conversions/s, paced by
//! the crystal. 256 summed conversions (20 bits) shifted right by 4 make one sample of
//! full scale 65,520 counts (`InstrumentConfig` full scale is 65,535) every 1.024 ms,
//! 976.5625 samples/s. 256× oversampling gains 4 bits of resolution when the input
//! noise dithers the ADC by about an LSB (a TIA output does); it also averages down
//! mains and switching ripple within each 1 ms.
//!
//! Nothing blocks: when the ring is full (nobody drained for 256 samples, 262 ms), the
//! newest sample is dropped and counted; `drain_samples` logs the count. No DMA
//! interrupt is used (embassy owns those vectors): TIM5 reads the DMA position (NDTR).
//!
//! ISR cost: 256 loads and adds per sample (~6 cycles each at opt-level "z") plus a short
//! critical section: ≲ 2,000 cycles ≈ 20 µs per 1.024 ms, ≈ 2 % of the CPU, at a lower
//! priority than the step timers, which preempt it.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU16, AtomicUsize, Ordering};

use defmt::warn;
use embassy_stm32::Peri;
use embassy_stm32::adc::Adc;
use embassy_stm32::gpio::Flex;
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac;
use embassy_stm32::pac::adc::vals as adc_vals;
use embassy_stm32::pac::dma::vals as dma_vals;
use embassy_stm32::peripherals::{ADC1, DMA2_CH0, PA1, TIM5};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::Timer;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;

/// Conversions summed into one sample.
const OVERSAMPLE: usize = 256;
/// Raw DMA buffer: 4 blocks, 4.1 ms; the 1 kHz decimation interrupt reads one or two.
const RAW_LEN: usize = 4 * OVERSAMPLE;
/// Decoded samples held for `drain_samples` (262 ms; the device drains every 1 ms).
const RING_LEN: usize = 256;
/// ADC1 channel of PA1.
const ADC_CHANNEL: u8 = 1;
/// DMA2 stream 0, channel 0 is ADC1.
const DMA_STREAM: usize = 0;

/// Written by the DMA, read by the TIM5 interrupt. Atomics, so that memory another bus
/// master writes is never assumed unchanged by the compiler.
static RAW: [AtomicU16; RAW_LEN] = [const { AtomicU16::new(0) }; RAW_LEN];
/// Next raw index the decimation reads.
static READ_POS: AtomicUsize = AtomicUsize::new(0);

/// Decoded samples, oldest at `head`.
struct Ring {
    samples: [u16; RING_LEN],
    head: usize,
    len: usize,
    /// Samples dropped because the ring was full, since the last report.
    lost: u32,
}

impl Ring {
    fn push(&mut self, sample: u16) {
        if self.len == RING_LEN {
            self.lost = self.lost.saturating_add(1);
            return;
        }
        self.samples[(self.head + self.len) % RING_LEN] = sample;
        self.len += 1;
    }

    fn pop(&mut self) -> Option<u16> {
        if self.len == 0 {
            return None;
        }
        let sample = self.samples[self.head];
        self.head = (self.head + 1) % RING_LEN;
        self.len -= 1;
        Some(sample)
    }
}

static RING: Mutex<CriticalSectionRawMutex, RefCell<Ring>> = Mutex::new(RefCell::new(Ring {
    samples: [0; RING_LEN],
    head: 0,
    len: 0,
    lost: 0,
}));

/// (Re)start the DMA stream from the start of `RAW`, then the conversions.
fn start_conversions() {
    let adc = pac::ADC1;
    let stream = pac::DMA2.st(DMA_STREAM);
    adc.cr2().modify(|w| w.set_dma(false));
    stream.cr().modify(|w| w.set_en(false));
    while stream.cr().read().en() {}
    // Clear the stream's flags (stream 0 is index 0 of LIFCR).
    pac::DMA2.ifcr(0).write(|w| {
        w.set_tcif(DMA_STREAM, true);
        w.set_htif(DMA_STREAM, true);
        w.set_teif(DMA_STREAM, true);
        w.set_dmeif(DMA_STREAM, true);
        w.set_feif(DMA_STREAM, true);
    });
    stream.par().write_value(adc.dr().as_ptr() as u32);
    stream.m0ar().write_value(RAW.as_ptr() as u32);
    stream.ndtr().write(|w| w.set_ndt(RAW_LEN as u16));
    stream.fcr().write(|w| w.set_dmdis(dma_vals::Dmdis::ENABLED)); // direct mode
    // No interrupt enables: embassy's DMA2_STREAM0 handler stays idle.
    stream.cr().write(|w| {
        w.set_chsel(0);
        w.set_dir(dma_vals::Dir::PERIPHERAL_TO_MEMORY);
        w.set_psize(dma_vals::Size::BITS16);
        w.set_msize(dma_vals::Size::BITS16);
        w.set_minc(true);
        w.set_circ(true);
        w.set_pl(dma_vals::Pl::HIGH);
        w.set_en(true);
    });
    READ_POS.store(0, Ordering::Relaxed);
    adc.sr().modify(|w| w.set_ovr(false));
    adc.cr2().modify(|w| w.set_dma(true));
    adc.cr2().modify(|w| w.set_swstart(true));
}

/// 1 kHz: turn every whole block of conversions the DMA has written into one sample.
#[interrupt]
fn TIM5() {
    let tim = pac::TIM5;
    if !tim.sr().read().uif() {
        return;
    }
    tim.sr().modify(|w| w.set_uif(false));
    if pac::ADC1.sr().read().ovr() {
        // The DMA missed a conversion (should not happen: it has priority "high" and
        // nothing else uses DMA2). The ADC stops on overrun: restart it.
        warn!("detector ADC overrun: conversions restarted");
        start_conversions();
        return;
    }
    let remaining = usize::from(pac::DMA2.st(DMA_STREAM).ndtr().read().ndt());
    let write = (RAW_LEN - remaining) % RAW_LEN;
    let mut read = READ_POS.load(Ordering::Relaxed);
    while (write + RAW_LEN - read) % RAW_LEN >= OVERSAMPLE {
        let sum: u32 = RAW[read..read + OVERSAMPLE]
            .iter()
            .map(|raw| u32::from(raw.load(Ordering::Relaxed)))
            .sum();
        // 256 × 4095 = 1,048,320 → 65,520: fits u16.
        let sample = (sum >> 4) as u16;
        RING.lock(|ring| ring.borrow_mut().push(sample));
        read = (read + OVERSAMPLE) % RAW_LEN;
    }
    READ_POS.store(read, Ordering::Relaxed);
}

/// The running ADC path: owns ADC1, the DMA stream, TIM5 and PA1.
pub struct DetectorAdc {
    _adc: Adc<'static, ADC1>,
    _dma: Peri<'static, DMA2_CH0>,
    _timer: Timer<'static, TIM5>,
    _pin: Flex<'static>,
}

impl DetectorAdc {
    /// Configure and start sampling at once.
    pub fn start(
        adc: Peri<'static, ADC1>,
        dma: Peri<'static, DMA2_CH0>,
        tim5: Peri<'static, TIM5>,
        pin: Peri<'static, PA1>,
    ) -> DetectorAdc {
        let mut pin = Flex::new(pin);
        pin.set_as_analog();
        // Clock on, prescaler (24 MHz), ADON.
        let adc = Adc::new(adc);
        // DMA2 clock (embassy's init enables it already; harmless if so).
        pac::RCC.ahb1enr().modify(|w| w.set_dma2en(true));
        let regs = pac::ADC1;
        regs.cr2().modify(|w| w.set_adon(false));
        regs.smpr2().modify(|w| w.set_smp(usize::from(ADC_CHANNEL), adc_vals::SampleTime::CYCLES84));
        regs.sqr1().modify(|w| w.set_l(0)); // one conversion per sequence
        regs.sqr3().modify(|w| w.set_sq(0, ADC_CHANNEL));
        regs.cr1().modify(|w| {
            w.set_scan(false);
            w.set_res(adc_vals::Res::BITS12);
        });
        regs.cr2().modify(|w| {
            w.set_cont(true);
            w.set_dds(adc_vals::Dds::CONTINUOUS);
            w.set_align(adc_vals::Align::RIGHT);
            w.set_exten(adc_vals::Exten::DISABLED);
            w.set_adon(true);
        });
        cortex_m::asm::delay(96 * 3); // tSTAB: 3 µs at 96 MHz
        start_conversions();

        let timer = Timer::new(tim5);
        timer.set_frequency(Hertz(1_000));
        timer.enable_update_interrupt(true);
        interrupt::TIM5.unpend();
        // Below the step timers: they preempt the decimation.
        interrupt::TIM5.set_priority(Priority::P2);
        // SAFETY: the TIM5 handler is defined above and shares state only through atomics
        // and a critical-section mutex.
        unsafe { interrupt::TIM5.enable() };
        timer.start();
        DetectorAdc {
            _adc: adc,
            _dma: dma,
            _timer: timer,
            _pin: pin,
        }
    }

    /// Hand every sample decoded since the last call to `sink`, oldest first, in short
    /// batches so that interrupts are never masked for long.
    pub fn drain(&mut self, sink: &mut dyn FnMut(u32)) {
        let mut lost = 0;
        loop {
            let mut batch = [0u16; 16];
            let mut n = 0;
            RING.lock(|ring| {
                let mut ring = ring.borrow_mut();
                lost += core::mem::take(&mut ring.lost);
                while n < batch.len() {
                    let Some(sample) = ring.pop() else { break };
                    batch[n] = sample;
                    n += 1;
                }
            });
            for &sample in &batch[..n] {
                sink(u32::from(sample));
            }
            if n < batch.len() {
                break;
            }
        }
        if lost > 0 {
            warn!("detector: {} samples lost (ring full, not drained for 262 ms)", lost);
        }
    }

    /// Forget the samples taken so far (and their losses).
    pub fn clear(&mut self) {
        RING.lock(|ring| {
            let mut ring = ring.borrow_mut();
            ring.head = 0;
            ring.len = 0;
            ring.lost = 0;
        });
    }
}
