//! Photodiode sampling: ADC1 on PA1 (IN1), converting continuously at a fixed rate, DMA
//! into a raw circular buffer, decimated by 256 in a 1 kHz TIM5 interrupt into a bounded
//! ring of 16-bit-effective samples that `drain_samples` empties.
//!
//! The decimation and the ring, with the overrun rule (an ADC overrun, a DMA lap, a full
//! ring: each reported), are the library's ([`firmware::sampling`]); this module runs the
//! ADC, the DMA and the interrupt, and hands the library the DMA position, the ADC's
//! overrun flag and the DWT cycle count.
//!
//! Rates: ADCCLK = PCLK2 96 MHz / 4 = 24 MHz (embassy's `Adc::new` prescaler); 84-cycle
//! sampling + 12-cycle conversion = 96 ADC clocks, so 250,000 conversions/s, one every 384
//! CPU cycles, paced by the crystal. 256 summed conversions (20 bits) shifted right by 4
//! make one sample of full scale 65,520 counts (`InstrumentConfig` full scale is 65,535)
//! every 1.024 ms, 976.5625 samples/s. 256× oversampling gains 4 bits of resolution when
//! the input noise dithers the ADC by about an LSB (a TIA output does); it also averages
//! down mains and switching ripple within each 1 ms.
//!
//! Nothing blocks. No DMA interrupt is used (embassy owns those vectors): TIM5 reads the
//! DMA position (NDTR), and the time since its last run tells one lap of the raw buffer
//! from two.
//!
//! ISR cost: 256 loads and adds per sample (~6 cycles each at opt-level "z") plus a short
//! critical section: ≲ 2,000 cycles ≈ 20 µs per 1.024 ms, ≈ 2 % of the CPU, at P1: below
//! the step timers, which preempt it, above USB and the time driver.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU16, Ordering};

use cortex_m::peripheral::DWT;
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
use embassy_stm32::timer::low_level::{RoundTo, Timer};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use firmware::sampling::{Decimator, RAW_LEN, SampleLoss, SampleRing};

/// CPU cycles per conversion: 96 ADC clocks at 24 MHz, at a 96 MHz SYSCLK.
const CYCLES_PER_CONVERSION: u32 = crate::SYSCLK_HZ / 250_000;
/// ADC1 channel of PA1.
const ADC_CHANNEL: u8 = 1;
/// DMA2 stream 0, channel 0 is ADC1.
const DMA_STREAM: usize = 0;

/// Written by the DMA, read by the TIM5 interrupt. Atomics, so that memory another bus
/// master writes is never assumed unchanged by the compiler.
static RAW: [AtomicU16; RAW_LEN] = [const { AtomicU16::new(0) }; RAW_LEN];

/// The decimation's state (TIM5 only) and the decoded samples (TIM5 and the device task).
struct Sampling {
    decimator: Decimator,
    ring: SampleRing,
}

static SAMPLING: Mutex<CriticalSectionRawMutex, RefCell<Sampling>> =
    Mutex::new(RefCell::new(Sampling { decimator: Decimator::new(CYCLES_PER_CONVERSION, 0), ring: SampleRing::new() }));

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
    // The clock first, then the DMA position: the lap test errs on the side of a loss.
    let now = DWT::cycle_count();
    let overrun = pac::ADC1.sr().read().ovr();
    let remaining = usize::from(pac::DMA2.st(DMA_STREAM).ndtr().read().ndt());
    let restart = SAMPLING.lock(|sampling| {
        let sampling = &mut *sampling.borrow_mut();
        let raw = |i: usize| RAW[i].load(Ordering::Relaxed);
        sampling.decimator.service(RAW_LEN - remaining, overrun, now, raw, &mut sampling.ring)
    });
    if restart {
        // The DMA missed a conversion and the ADC stopped (it should not: the DMA has
        // priority "high" and nothing else uses DMA2): restart from slot 0.
        start_conversions();
        let now = DWT::cycle_count();
        SAMPLING.lock(|sampling| sampling.borrow_mut().decimator.restart(now));
    }
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

        SAMPLING.lock(|sampling| sampling.borrow_mut().decimator.restart(DWT::cycle_count()));
        let timer = Timer::new(tim5);
        timer.set_frequency(Hertz(1_000), RoundTo::Slower);
        timer.enable_update_interrupt(true);
        interrupt::TIM5.unpend();
        // Below the step timers (they preempt the decimation), above USB and the time
        // driver: it has 2 ms before the DMA laps the raw buffer.
        interrupt::TIM5.set_priority(Priority::P1);
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
    /// batches so that interrupts are never masked for long; the loss since the last
    /// drain, if any.
    pub fn drain(&mut self, sink: &mut dyn FnMut(u32)) -> Result<(), SampleLoss> {
        let mut loss = None;
        loop {
            let mut batch = [0u16; 16];
            let n = SAMPLING.lock(|sampling| {
                let mut sampling = sampling.borrow_mut();
                loss = loss.or(sampling.ring.take_loss());
                sampling.ring.pop_into(&mut batch)
            });
            for &sample in &batch[..n] {
                sink(u32::from(sample));
            }
            if n < batch.len() {
                break;
            }
        }
        match loss {
            Some(loss) => {
                warn!("detector: samples lost ({})", loss);
                Err(loss)
            }
            None => Ok(()),
        }
    }

    /// An overrun of the ADC path since the last call (drained or not).
    pub fn take_fault(&mut self) -> Option<SampleLoss> {
        SAMPLING.lock(|sampling| sampling.borrow_mut().ring.take_fault())
    }

    /// Forget the samples taken so far (not an overrun: see `firmware::sampling`).
    pub fn clear(&mut self) {
        SAMPLING.lock(|sampling| sampling.borrow_mut().ring.clear());
    }
}
